"""Report figures: matplotlib `Figure` objects (no pyplot, no global backend) as data: URIs.

Each builder takes analysis results (per-point tables, fits, curves) and returns a Figure;
`encode` turns it into a `data:image/svg+xml` or `data:image/png` URI for an <img>.
"""

from __future__ import annotations

import base64
import io
import math
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field

import matplotlib
import numpy as np
from matplotlib import colormaps
from matplotlib.axes import Axes
from matplotlib.container import ErrorbarContainer
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from rigtool.analysis.curves import CommandCurve
from rigtool.analysis.efficiency import efficiency_n_per_w, efficiency_se_n_per_w
from rigtool.analysis.fits import Coefficient
from rigtool.analysis.results import Hysteresis, TareDrift, VoltageLaw
from rigtool.analysis.steady import PointTable
from rigtool.models import laws

FWD = "#1f5fa8"
REV = "#c0392b"
GREY = "#8c8c8c"
DEAD = "#d9d9d9"
SAT = "#f5a623"
WINDOW = "#cfe8cf"
BAND = "#9ecae1"
ZOOM_FRACTION = 0.35
WIDE = (7.2, 3.6)
TALL = (7.2, 4.6)
SMALL = (4.6, 3.1)
MAX_TRACE_POINTS = 4000
GAP_FACTOR = 3.0  # a time step this many times the typical one is a gap: lines break there
LEGEND_ROW_IN = 0.2
STYLE = {
    "font.size": 8.5,
    "axes.titlesize": 9.5,
    "axes.labelsize": 8.5,
    "legend.fontsize": 7.5,
    "xtick.labelsize": 7.5,
    "ytick.labelsize": 7.5,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "grid.linewidth": 0.5,
    "lines.markersize": 3.5,
    "svg.fonttype": "path",
    "svg.hashsalt": "rigtool-report",
    "axes.titley": 1.0,  # a fixed title position: auto-placing it measures every tick label
    "axes.formatter.useoffset": False,
}


@dataclass
class Trace:
    """Samples of one point for the time-series view; t_s starts at the first sample."""

    label: str
    t_s: np.ndarray
    thrust_n: np.ndarray
    window_start_s: float
    mean_n: float
    spans_s: list[tuple[float, float]] = field(default_factory=list)


@contextmanager
def style() -> Iterator[None]:
    """Report look (font sizes, grid) for figures created inside the block."""
    with matplotlib.rc_context(STYLE):
        yield


def encode(fig: Figure, fmt: str = "svg", dpi: int = 110) -> str:
    """The figure as a data: URI (SVG or PNG), metadata stripped so output is reproducible."""
    buf = io.BytesIO()
    if fmt == "svg":
        fig.savefig(buf, format="svg", metadata={"Date": None, "Creator": None})
        mime = "image/svg+xml"
    elif fmt == "png":
        fig.savefig(buf, format="png", dpi=dpi, metadata={"Software": None})
        mime = "image/png"
    else:
        raise ValueError(f"unknown image format {fmt!r} (svg or png)")
    return f"data:{mime};base64,{base64.b64encode(buf.getvalue()).decode('ascii')}"


def figure(size: tuple[float, float], *, below_in: float = 0.0, hspace: float = 0.1) -> Figure:
    """A figure with fixed margins in inches (a layout engine would double the render time)."""
    w, h = size
    fig = Figure(figsize=size)
    fig.subplots_adjust(left=0.72 / w, right=1 - 0.15 / w, top=1 - 0.3 / h,
                        bottom=(0.48 + below_in) / h, hspace=hspace)
    return fig


def _has_data(handle: object) -> bool:
    """False for a line (or the data line of an errorbar) drawn from empty arrays."""
    line = handle.lines[0] if isinstance(handle, ErrorbarContainer) else handle
    return not isinstance(line, Line2D) or len(line.get_xdata()) > 0


def _entries(ax: Axes) -> tuple[list, list[str]]:
    pairs = [(h, label) for h, label in zip(*ax.get_legend_handles_labels(), strict=True)
             if _has_data(h)]
    return [h for h, _ in pairs], [label for _, label in pairs]


def _legend(ax: Axes, **kw: object) -> None:
    handles, labels = _entries(ax)
    if handles:
        ax.legend(handles, labels, frameon=False, **kw)


def _fig_legend(fig: Figure, ax: Axes, ncol: int) -> None:
    """Legend centred under the axes, in the bottom margin reserved by `_rows`."""
    handles, labels = _entries(ax)
    if handles:
        fig.legend(handles, labels, loc="lower center", ncol=ncol, frameon=False,
                   bbox_to_anchor=(0.5, 0.0))


def _rows(ax: Axes, ncol: int) -> float:
    """Bottom margin (inches) that a figure legend with `ncol` columns needs under `ax`."""
    n = len(_entries(ax)[0])
    return LEGEND_ROW_IN * math.ceil(n / ncol) + 0.1


def _cp_model(fits: dict[str, Coefficient], n: np.ndarray) -> np.ndarray:
    """C_p |n| n with the forward or reverse coefficient by the sign of n (NaN without one)."""
    out = np.full(n.shape, np.nan)
    for key, s in (("fwd", 1.0), ("rev", -1.0)):
        c = fits.get(f"C_p_{key}")
        if c is not None:
            side = np.sign(n) == s
            out[side] = laws.thrust_from_speed(n[side], c.value, c.value)
    return out


def thrust_speed(points: PointTable, fits: dict[str, Coefficient]) -> Figure:
    """Thrust vs propeller speed with the C_p |n| n fits, and a residuals panel below; thrust
    is taken relative to the estimated sensor zero (offset and drift), as the fit saw it."""
    fig = figure(TALL, hspace=0.08)
    top, bottom = fig.subplots(2, 1, sharex=True, height_ratios=[3, 1.3])
    n, f = points.speed_signed_rpm, points.thrust_corrected_n
    used = points.used_in_fits
    other = ~used & np.isfinite(n) & np.isfinite(f)
    top.plot(n[other], f[other], "o", mfc="none", color=GREY, label="not in fit")
    for key, s, color, word in (("fwd", 1, FWD, "forward"), ("rev", -1, REV, "reverse")):
        m = used & (np.sign(n) == s)
        top.errorbar(n[m], f[m], yerr=1.96 * np.nan_to_num(points.thrust.se[m]), fmt="o",
                     color=color, label=f"{word} points")
        c = fits.get(f"C_p_{key}")
        if c is not None and m.any():
            edge = float(np.nanmax(np.abs(n[m | (np.sign(n) == s)])))
            grid = s * np.linspace(0, edge * 1.03, 200)
            top.plot(grid, laws.thrust_from_speed(grid, c.value, c.value), "-", color=color, lw=1.2,
                     label=f"fit C_p_{key} = {c.value:.4g} N/(r/min)²")
    top.axhline(0, color="k", lw=0.6)
    top.set_ylabel("thrust − zero (N)")
    top.set_title("Thrust vs propeller speed, f = C_p |n| n")
    _legend(top, loc="upper left")
    resid = f - _cp_model(fits, n)
    for s, color in ((1, FWD), (-1, REV)):
        m = used & (np.sign(n) == s)
        bottom.plot(n[m], resid[m], "o", color=color)
    bottom.axhline(0, color="k", lw=0.6)
    bottom.set_xlabel("propeller speed n (r/min)")
    bottom.set_ylabel("residual (N)")
    return fig


def current_speed(points: PointTable, fits: dict[str, Coefficient]) -> Figure:
    """Motor current vs propeller speed with I = C_n |n|^3 + I_0 (and the free-exponent fit)."""
    fig = figure(WIDE)
    ax = fig.subplots()
    n, cur = points.speed_signed_rpm, points.current.mean.copy()
    rev = points.used_in_fits & (n < 0) & np.isfinite(cur)
    if rev.any() and np.median(cur[rev]) < 0:
        cur = np.abs(cur)
    used = points.used_in_fits & np.isfinite(cur)
    other = ~used & np.isfinite(n) & np.isfinite(cur)
    ax.plot(n[other], cur[other], "o", mfc="none", color=GREY, label="not in fit")
    ax.plot(n[used & (n > 0)], cur[used & (n > 0)], "o", color=FWD, label="forward points")
    ax.plot(n[used & (n < 0)], cur[used & (n < 0)], "o", color=REV, label="reverse points")
    seen = n[np.isfinite(n)]
    grid = np.linspace(min(float(seen.min()), 0.0) * 1.03, max(float(seen.max()), 0.0) * 1.03, 400)
    cn, i0 = fits["C_n"], fits["I_0"]
    ax.plot(grid, laws.current_from_speed(grid, cn.value, i0.value), "k-", lw=1.2,
            label=f"I = C_n |n|³ + I_0, C_n = {cn.value:.4g} A/(r/min)³, I_0 = {i0.value:.3g} A")
    if "k_free" in fits and "C_free" in fits and "I_0_free" in fits:
        k, c, j = fits["k_free"].value, fits["C_free"].value, fits["I_0_free"].value
        ax.plot(grid, laws.current_from_speed(grid, c, j, k), "--", color=SAT, lw=1.0,
                label=f"free exponent: k = {k:.3g}")
    ax.set_xlabel("propeller speed n (r/min)")
    ax.set_ylabel("motor current |I| (A)")
    ax.set_title("Current vs propeller speed")
    fig.subplots_adjust(bottom=(0.48 + _rows(ax, 2)) / WIDE[1])
    _fig_legend(fig, ax, 2)
    return fig


def _half_step(command: np.ndarray) -> float:
    d = np.diff(np.unique(command))
    return float(np.min(d)) / 2 if d.size else 0.5


def zoom_range(curve: CommandCurve) -> tuple[float, float] | None:
    """Command window around the usable (live, unsaturated) ranges when they are a narrow part."""
    usable = [b.usable for b in curve.branches if b.usable]
    if not usable or curve.command.size < 2:
        return None
    lo, hi = min(u[0] for u in usable), max(u[1] for u in usable)
    span = float(curve.command[-1] - curve.command[0])
    if hi - lo >= ZOOM_FRACTION * span:
        return None
    pad = 0.15 * (hi - lo) + 2 * _half_step(curve.command)
    return lo - pad, hi + pad


def _draw_curve(ax: Axes, curve: CommandCurve, unit: str) -> None:
    c, h = curve.command, _half_step(curve.command)
    for i, (lo, hi) in enumerate(curve.dead_zones):
        ax.axvspan(lo - h, hi + h, color=DEAD, alpha=0.7, lw=0,
                   label="dead zone" if i == 0 else None)
    for i, (lo, hi) in enumerate(curve.saturated):
        ax.axvspan(lo - h, hi + h, facecolor="none", edgecolor=SAT, alpha=0.6, hatch="///", lw=0,
                   label="saturated" if i == 0 else None)
    ax.fill_between(c, curve.thrust_min_n, curve.thrust_max_n, color=BAND, alpha=0.45, lw=0,
                    label="sample min..max")
    dead = curve.state == "dead"
    ax.plot(c[dead], curve.thrust_mean_n[dead], ".", color=GREY, label="dead (mean)")
    for i, b in enumerate(curve.branches):
        color = FWD if b.direction == "forward" else REV
        m = curve.branch == i
        word = b.direction + (", inverted" if b.inverted else "")
        ax.plot(c[m], curve.thrust_mean_n[m], ".", color=color, label=f"{word} (mean)")
        ax.plot(b.command, b.thrust_fit_n, "-", color=color, lw=1.1)
    for i, x in enumerate(curve.break_aways):
        ax.axvline(x, color="k", ls="--", lw=0.9, label="break-away" if i == 0 else None)
        ax.annotate(f"{x:g}", (x, 1.0), xycoords=("data", "axes fraction"),
                    xytext=(3, -10), textcoords="offset points", fontsize=7.5)
    ax.axhline(0, color="k", lw=0.6)
    ax.set_xlabel(f"command ({unit})")
    ax.set_ylabel("thrust (N)")


def command_curve(curve: CommandCurve, unit: str) -> Figure:
    """Thrust vs command: dead zones shaded, saturated ranges hatched, break-aways, monotone fit.

    A second panel zooms on the usable ranges when they cover a small part of the command span.
    """
    zoom = zoom_range(curve)
    size = (TALL[0], TALL[1] + (2.6 if zoom else 0.0))
    fig = figure(size, hspace=0.35)
    axes = fig.subplots(2 if zoom else 1, 1, squeeze=False)[:, 0]
    for ax in axes:
        _draw_curve(ax, curve, unit)
    axes[0].set_title("Command curve: thrust vs command (lines: monotone fit per branch)")
    if zoom:
        ax = axes[1]
        ax.set_xlim(*zoom)
        inside = (curve.command >= zoom[0]) & (curve.command <= zoom[1])
        lo = np.nanmin(np.r_[curve.thrust_min_n[inside], 0.0])
        hi = np.nanmax(np.r_[curve.thrust_max_n[inside], 0.0])
        pad = 0.06 * (hi - lo or 1.0)
        ax.set_ylim(lo - pad, hi + pad)
        ax.set_title(f"Zoom on the usable ranges, {zoom[0]:g} .. {zoom[1]:g} {unit}")
    fig.subplots_adjust(bottom=(0.48 + _rows(axes[0], 4)) / size[1])
    _fig_legend(fig, axes[0], 4)
    return fig


def inverse_map(curve: CommandCurve, unit: str) -> Figure:
    """Command vs thrust over each branch's usable range (the inverse lookup table)."""
    fig = figure(SMALL)
    ax = fig.subplots()
    for b in curve.branches:
        if b.lut_thrust_n.size:
            color = FWD if b.direction == "forward" else REV
            ax.plot(b.lut_thrust_n, b.lut_command, ".-", color=color, lw=1.0, label=b.direction)
    ax.axvline(0, color="k", lw=0.6)
    ax.set_xlabel("thrust (N)")
    ax.set_ylabel(f"command ({unit})")
    ax.set_title("Inverse map: command for a wanted thrust")
    _legend(ax, loc="best")
    return fig


def hysteresis(h: Hysteresis, unit: str) -> Figure:
    """Up-sweep minus down-sweep thrust vs command, with 95 % error bars."""
    fig = figure(WIDE)
    ax = fig.subplots()
    ax.errorbar(h.command, h.diff_n, yerr=1.96 * np.nan_to_num(h.diff_se_n), fmt="o-",
                color=FWD, lw=0.8, capsize=2)
    ax.axhline(0, color="k", lw=0.6)
    ax.set_xlabel(f"command ({unit})")
    ax.set_ylabel("thrust up − down (N)")
    ax.set_title(f"Hysteresis: max |up − down| = {h.max_abs_n:.3g} N at {h.at_command:g} {unit}")
    return fig


def spread(points: PointTable, unit: str) -> Figure:
    """Per-point standard deviation and |max − mean| of the thrust over the steady window."""
    fig = figure(WIDE)
    ax = fig.subplots()
    t = points.thrust
    ok = points.status == "ok"
    dead = ok & points.dead
    live = ok & ~points.dead
    ax.plot(points.command[live], np.abs(t.peak - t.mean)[live], "x", color=SAT,
            label="|max − mean| (extreme on the side of the mean)")
    ax.plot(points.command[live], t.std[live], ".", color=FWD, label="standard deviation")
    if dead.any():
        ax.plot(points.command[dead], t.std[dead], ".", color=GREY, label="std, dead zone")
    ax.set_ylim(bottom=0)
    ax.set_xlabel(f"command ({unit})")
    ax.set_ylabel("thrust spread (N)")
    ax.set_title("Per-point spread of the thrust over the steady window")
    fig.subplots_adjust(bottom=(0.48 + _rows(ax, 3)) / WIDE[1])
    _fig_legend(fig, ax, 3)
    return fig


def efficiency(points: PointTable) -> Figure:
    """Thrust per electrical watt (g/W, with 95 % bars) and electrical power (W) vs thrust."""
    fig = figure(WIDE)
    eff_ax, pow_ax = fig.subplots(1, 2)
    ok = (points.status == "ok") & ~points.dead & np.isfinite(efficiency_n_per_w(points))
    f = points.thrust_corrected_n
    grams = 1000.0 / 9.80665
    for mask, color, label in ((ok & (f >= 0), FWD, "forward"), (ok & (f < 0), REV, "reverse")):
        if not mask.any():
            continue
        eff_ax.errorbar(np.abs(f[mask]), grams * efficiency_n_per_w(points)[mask],
                        yerr=1.96 * grams * np.nan_to_num(efficiency_se_n_per_w(points)[mask]),
                        fmt=".", color=color, label=label)
        pow_ax.plot(np.abs(f[mask]), points.power.mean[mask], ".", color=color, label=label)
    eff_ax.set_xlabel("|thrust| (N)")
    eff_ax.set_ylabel("efficiency (g/W)")
    eff_ax.set_ylim(bottom=0)
    pow_ax.set_xlabel("|thrust| (N)")
    pow_ax.set_ylabel("electrical power V·|I| (W)")
    fig.subplots_adjust(wspace=0.3, bottom=(0.48 + _rows(eff_ax, 2)) / WIDE[1])
    _fig_legend(fig, eff_ax, 2)
    return fig


def voltage_law(law: VoltageLaw, points_by_voltage: Sequence[tuple[float, PointTable]]) -> Figure:
    """C_n per supply voltage with the fitted law k U^b, and current vs thrust per voltage."""
    fig = figure(WIDE)
    cn_ax, map_ax = fig.subplots(1, 2)
    use = [v for v in law.points if v.cn is not None and np.isfinite(v.cn.value)]
    u = np.array([v.voltage_v for v in use])
    cn = np.array([v.cn.value for v in use])
    err = np.array([[v.cn.value - v.cn.lo for v in use], [v.cn.hi - v.cn.value for v in use]])
    cn_ax.errorbar(u, cn, yerr=err, fmt="o", color=FWD, label="C_n per voltage (95 %)")
    grid = np.linspace(u.min() * 0.95, u.max() * 1.05, 100)
    cn_ax.plot(grid, law.cn_at(grid), "-", color=GREY,
               label=f"k U^b, b = {law.b.value:.3f}")
    cn_ax.set_xlabel("supply voltage U (V)")
    cn_ax.set_ylabel("C_n (A/(r/min)³)")
    colors = _colors(len(points_by_voltage))
    for (volts, p), color in zip(points_by_voltage, colors, strict=True):
        ok = (p.status == "ok") & ~p.dead & np.isfinite(p.current.mean)
        order = np.argsort(p.thrust_corrected_n[ok])
        map_ax.plot(p.thrust_corrected_n[ok][order], p.current.mean[ok][order], ".-", ms=3,
                    lw=0.8, color=color, label=f"{volts:g} V")
    map_ax.set_xlabel("thrust (N)")
    map_ax.set_ylabel("current (A)")
    fig.subplots_adjust(wspace=0.35, bottom=(0.48 + _rows(map_ax, 5)) / WIDE[1])
    _fig_legend(fig, map_ax, 5)
    _legend(cn_ax, fontsize="small")
    return fig


def step_responses(t_s: np.ndarray, measured: np.ndarray, fitted: dict[str, np.ndarray],
                   switch_s: np.ndarray) -> Figure:
    """Measured thrust through the steps with each fitted model; command steps marked."""
    fig = figure(WIDE)
    ax = fig.subplots()
    t, f = _decimate(t_s, measured, 20_000)
    ax.plot(t, f, "-", lw=0.5, color=GREY, label="measured")
    for (name, y), color in zip(fitted.items(), (FWD, REV, SAT), strict=False):
        tt, yy = _decimate(t_s, y, 20_000)
        ax.plot(tt, yy, "-", lw=1.0, color=color, label=f"{name} model")
    for s in switch_s:
        ax.axvline(s, color=GREY, lw=0.4, ls=":")
    ax.set_xlabel("run time (s)")
    ax.set_ylabel("thrust (N)")
    _legend(ax, fontsize="small")
    return fig


def _colors(n: int) -> list:
    """`n` colours along a perceptually ordered map (low voltage dark, high light)."""
    return [colormaps["viridis"](x) for x in np.linspace(0.0, 0.85, max(n, 1))][:n]


def tare_drift(drift: TareDrift) -> Figure:
    """Thrust-channel tare bias (relative to the first tare) vs time, with the linear trend."""
    fig = figure(WIDE)
    ax = fig.subplots()
    span_h = float(np.ptp(drift.t_s)) / 3600.0
    scale, tunit = (3600.0, "h") if span_h >= 2 else (60.0, "min")
    x = (drift.t_s - drift.t_s[0]) / scale
    ax.plot(x, drift.bias_n, "o", color=FWD, label="tare bias")
    s = drift.slope
    trend = s.value * (drift.t_s - drift.t_s[0]) / 3600.0
    trend += float(np.mean(drift.bias_n - trend))
    interval = (f"95 %: {s.lo:.3g} .. {s.hi:.3g}" if math.isfinite(s.lo) and math.isfinite(s.hi)
                else f"{s.n} tares: no interval")
    ax.plot(x, trend, "-", color=REV, lw=1.0, label=f"trend {s.value:.3g} N/h ({interval})")
    ax.set_xlabel(f"time since first tare ({tunit})")
    ax.set_ylabel("bias on the thrust channel (N)")
    ax.set_title("Tare drift")
    _legend(ax, loc="best")
    return fig


def gap_starts(t: np.ndarray, segment: np.ndarray | None = None) -> np.ndarray:
    """Indices i where a gap lies between samples i-1 and i: a time step over GAP_FACTOR times
    the median one, or (given `segment`, e.g. the point of each sample) a new segment."""
    t = np.asarray(t, dtype=float)
    if t.size < 2:
        return np.zeros(0, dtype=int)
    dt = np.diff(t)
    step = dt[np.isfinite(dt) & (dt > 0)]
    jump = dt > GAP_FACTOR * float(np.median(step)) if step.size else np.zeros(dt.size, bool)
    if segment is not None:
        jump |= np.diff(np.asarray(segment)) != 0
    return np.flatnonzero(jump) + 1


def break_at_gaps(t: np.ndarray, *ys: np.ndarray,
                  segment: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
    """`t` and each of `ys` with a NaN inserted at every gap (`gap_starts`), so that no line or
    band is drawn across a rest, a depth move or lost samples."""
    at = gap_starts(t, segment)
    return tuple(np.insert(np.asarray(a, dtype=float), at, np.nan) for a in (t, *ys))


def _decimate(t: np.ndarray, y: np.ndarray, limit: int) -> tuple[np.ndarray, np.ndarray]:
    """A trace to plot: min/max per bucket past `limit` samples (spikes survive), broken by a
    NaN at every gap in time."""
    at = gap_starts(t)
    if not at.size:
        return _min_max(t, y, limit)
    pieces = [_min_max(tt, yy, max(2, limit * tt.size // t.size))
              for tt, yy in zip(np.split(t, at), np.split(y, at), strict=True)]
    starts = np.cumsum([0] + [tt.size for tt, _ in pieces[:-1]])[1:]
    return (np.insert(np.concatenate([tt for tt, _ in pieces]).astype(float), starts, np.nan),
            np.insert(np.concatenate([yy for _, yy in pieces]).astype(float), starts, np.nan))


def _min_max(t: np.ndarray, y: np.ndarray, limit: int) -> tuple[np.ndarray, np.ndarray]:
    """Min/max per bucket so spikes survive when a trace has more than `limit` samples."""
    if t.size <= limit:
        return t, y
    buckets = limit // 2
    edges = np.linspace(0, t.size, buckets + 1).astype(int)
    lo = np.minimum.reduceat(y, edges[:-1])
    hi = np.maximum.reduceat(y, edges[:-1])
    tt = np.repeat(t[edges[:-1]], 2)
    return tt, np.column_stack([lo, hi]).ravel()


def time_series(traces: Sequence[Trace]) -> Figure:
    """Thrust vs time within each chosen point, steady window shaded, window mean dashed."""
    panel_in, legend_in = 1.45, 0.35
    size = (7.2, 0.8 + legend_in + panel_in * len(traces))
    fig = figure(size, below_in=legend_in, hspace=0.5)
    axes = fig.subplots(len(traces), 1, squeeze=False)[:, 0]
    for ax, tr in zip(axes, traces, strict=True):
        end = float(tr.t_s[-1]) if tr.t_s.size else 1.0
        ax.axvspan(tr.window_start_s, end, color=WINDOW, lw=0, label="steady window")
        for a, b in tr.spans_s:
            ax.axvspan(a, b, facecolor="none", edgecolor=REV, alpha=0.45, hatch="////", lw=0,
                       label="ventilation (simulator truth)")
        t, y = _decimate(tr.t_s, tr.thrust_n, MAX_TRACE_POINTS)
        ax.plot(t, y, "-", color=FWD, lw=0.5, label="thrust samples")
        ax.plot([tr.window_start_s, end], [tr.mean_n, tr.mean_n], "--", color=REV, lw=1.0,
                label="window mean")
        ax.set_title(f"{tr.label}; window mean {tr.mean_n:.4g} N", loc="left", fontsize=8.5)
        ax.set_ylabel("thrust (N)")
        ax.set_xlim(0, end)
    axes[-1].set_xlabel("time since the first acquired sample of the point (s)")
    seen: dict[str, object] = {}
    for ax in axes:
        for h, label in zip(*_entries(ax), strict=True):
            seen.setdefault(label, h)
    fig.legend(list(seen.values()), list(seen), loc="lower center", ncol=len(seen),
               frameon=False, bbox_to_anchor=(0.5, 0.0))
    return fig
