"""Self-contained HTML report of `rigtool compare`: overlaid curves, deviations, corrections."""

from __future__ import annotations

from pathlib import Path

import jinja2
import numpy as np
from matplotlib.figure import Figure

from rigtool.analysis.compare import CompareResult
from rigtool.artefacts.write import atomic_write
from rigtool.ids import utc_now
from rigtool.report import figures as fg
from rigtool.report.html import fmt_num
from rigtool.units import unit_label
from rigtool.version import __version__

REPORT_FILE = "compare.html"
SIZE = (7.2, 3.8)


def _axes(title: str, xlabel: str, ylabel: str) -> tuple[Figure, object]:
    fig = Figure(figsize=SIZE)
    fig.subplots_adjust(left=0.1, right=0.98, top=0.92, bottom=0.14)
    ax = fig.add_subplot()
    ax.set(title=title, xlabel=xlabel, ylabel=ylabel)
    return fig, ax


def curves_figure(result: CompareResult, unit: str) -> Figure:
    """Mean thrust vs command of every run, overlaid; dead zones shaded."""
    fig, ax = _axes("Thrust vs command", f"command ({unit})", "thrust (N)")
    for curve in result.curves:
        line, = ax.plot(curve.command, curve.thrust_n, "o", ms=2.5, label=curve.label)
        grid = np.linspace(curve.command[0], curve.command[-1], 400)
        ax.plot(grid, curve.f(grid), "-", lw=0.8, color=line.get_color())
        for lo, hi in curve.dead_zones:
            ax.axvspan(lo, hi, color=fg.DEAD, alpha=0.35, lw=0)
    ax.legend(frameon=False, fontsize=7)
    return fig


def deviation_figure(result: CompareResult, unit: str, after: bool) -> Figure:
    """Relative deviation from the reference per command, over the shared usable range."""
    which = "after correction" if after else "before correction"
    fig, ax = _axes(f"Deviation from {result.reference_label}, {which}", f"command ({unit})",
                    "deviation (%)")
    colours = {}
    for m in result.matches:
        values = m.after_n if after else m.before_n
        for curve in result.curves:
            dev = 100 * (values[curve.run_id] - m.reference_n) / np.abs(m.reference_n)
            kw = {"color": colours[curve.run_id]} if curve.run_id in colours else {
                "label": curve.label}
            line, = ax.plot(m.command, dev, "-", lw=1, **kw)
            colours[curve.run_id] = line.get_color()
    ax.axhspan(-2, 2, color=fg.WINDOW, alpha=0.5, lw=0, label="±2 %")
    ax.legend(frameon=False, fontsize=7)
    return fig


def render_compare(result: CompareResult, image_format: str = "svg") -> str:
    """The comparison as one HTML string (figures embedded as data: URIs)."""
    unit = unit_label(result.command_unit)
    with fg.style():
        figures = [
            ("Command curves", fg.encode(curves_figure(result, unit), image_format)),
            ("Deviation before correction",
             fg.encode(deviation_figure(result, unit, after=False), image_format)),
            ("Deviation after correction",
             fg.encode(deviation_figure(result, unit, after=True), image_format)),
        ]
    env = jinja2.Environment(loader=jinja2.PackageLoader("rigtool.report", "templates"),
                             autoescape=True, trim_blocks=True, lstrip_blocks=True,
                             undefined=jinja2.StrictUndefined)
    env.filters["num"] = fmt_num
    return env.get_template("compare.html").render(
        result=result, unit=unit, figures=figures, generated=utc_now(),
        version=__version__)


def write_compare_report(result: CompareResult, out_dir: Path, image_format: str = "svg") -> Path:
    """Write `out_dir`/compare.html and return its path."""
    out_dir.mkdir(parents=True, exist_ok=True)
    return atomic_write(out_dir / REPORT_FILE, render_compare(result, image_format))
