"""Self-contained HTML report of `rigtool identify`: parameters with intervals, the structure
chosen per DOF, the methods side by side, and held-out trajectories against the model."""

from __future__ import annotations

import jinja2
from matplotlib.figure import Figure

from rigtool.analysis.vehicle.identify import Identification
from rigtool.analysis.vehicle.model import DOFS, NAMES, UNITS, VELOCITY
from rigtool.ids import utc_now
from rigtool.report import figures as fg
from rigtool.report.html import fmt_num
from rigtool.version import __version__

REPORT_FILE = "identification.html"


def held_out_figure(ident: Identification) -> Figure:
    """Measured and predicted velocities of the first held-out segments, one panel per DOF."""
    fig = Figure(figsize=(7.2, 6.4))
    fig.subplots_adjust(left=0.1, right=0.98, top=0.95, bottom=0.07, hspace=0.45, wspace=0.3)
    for n, dof in enumerate(ident.dofs):
        i = DOFS.index(dof)
        ax = fig.add_subplot(3, 2, n + 1)
        for k in range(ident.trace_measured.shape[0]):
            shift = k * ident.trace_t_s[-1]
            ax.plot(ident.trace_t_s + shift, ident.trace_measured[k, :, i], ".", ms=1.5,
                    color=fg.GREY, label="measured" if k == 0 else None)
            ax.plot(ident.trace_t_s + shift, ident.trace_predicted[k, :, i], "-", lw=1,
                    color=fg.FWD, label="model" if k == 0 else None)
        ax.set(title=dof, xlabel="t (s), held-out segments end to end",
               ylabel=f"{VELOCITY[i]} ({UNITS[i]})")
        if n == 0:
            ax.legend(frameon=False)
    return fig


def render_identification(ident: Identification, vehicle_name: str,
                          image_format: str = "svg") -> str:
    """The identification as one HTML string (figures embedded as data: URIs)."""
    with fg.style():
        figure = fg.encode(held_out_figure(ident), image_format)
    env = jinja2.Environment(loader=jinja2.PackageLoader("rigtool.report", "templates"),
                             autoescape=True, trim_blocks=True, lstrip_blocks=True,
                             undefined=jinja2.StrictUndefined)
    env.filters["num"] = fmt_num
    return env.get_template("vehicle.html").render(
        ident=ident, name=vehicle_name, figure=figure, names=NAMES, generated=utc_now(),
        version=__version__)
