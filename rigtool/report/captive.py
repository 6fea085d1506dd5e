"""The report's "Captive test" section: the damping laws per axis, lift and drag per angle,
and force against flow with the fitted laws."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from matplotlib.figure import Figure

from rigtool.analysis.captive import CaptiveLaw, CaptiveResult
from rigtool.analysis.fits import Coefficient
from rigtool.report import figures as fg


@dataclass
class CaptiveView:
    """What the template renders: coefficient rows, refusals, lift/drag rows and the figure."""

    angle: str
    rows: list[Coefficient]
    refused: list[str]
    lift_drag: list[tuple[float, list[Coefficient | None], str]]
    figure_uri: str
    caption: str


def force_flow_figure(result: CaptiveResult) -> Figure:
    """Per axis fitted, force (zero per angle removed) against its flow component, points with
    95 % bars and the fitted law."""
    fitted = [law for law in result.laws if law.linear is not None]
    fig = fg.figure((7.2, 3.4))
    axes = fig.subplots(1, max(1, len(fitted)), squeeze=False)[0]
    p = result.points
    for ax, law in zip(axes, fitted, strict=False):
        k = "XYZ".index(law.force)
        nu, y = p.velocity_mps[:, k], p.mean[:, k] - _offsets(law, p.angle_deg)
        for j, a in enumerate(np.unique(p.angle_deg)):
            m = p.angle_deg == a
            ax.errorbar(nu[m], y[m], yerr=1.96 * np.nan_to_num(p.se[m, k]), fmt="o", ms=3,
                        color=f"C{j}", label=f"{a:g}°")
        grid = np.linspace(nu.min(), nu.max(), 200)
        ax.plot(grid, law.linear.value * grid + law.quadratic.value * grid * np.abs(grid), "k-",
                lw=1.0, label="fit")
        ax.axhline(0, color="k", lw=0.5)
        ax.set_xlabel(f"{law.velocity} (m/s)")
        ax.set_ylabel(f"{law.force} − zero (N)")
        q = law.quadratic.value
        ax.set_title(f"{law.force} = {law.linear.value:.3g} {law.velocity} "
                     f"{'+' if q >= 0 else '−'} {abs(q):.3g} {law.velocity}|{law.velocity}|",
                     fontsize=8)
    axes[0].legend(loc="best", fontsize=6, title=result.angle, title_fontsize=6)
    return fig


def _offsets(law: CaptiveLaw, angle_deg: np.ndarray) -> np.ndarray:
    """Each point's fitted zero (its angle's offset)."""
    lookup = dict(zip(law.offset_angles_deg.tolist(), law.offsets.tolist(), strict=True))
    return np.array([lookup.get(float(a), 0.0) for a in angle_deg])


def captive_view(result: CaptiveResult | None, fmt: str) -> CaptiveView | None:
    """The section's view (None for a run without a captive axis)."""
    if result is None:
        return None
    rows = [c for law in result.laws for c in (law.linear, law.quadratic) if c is not None]
    refused = [w.removeprefix("captive: ") for w in result.warnings]
    lift_drag = [(ld.angle_deg, [ld.drag_linear, ld.drag_quadratic, ld.lift_linear,
                                 ld.lift_quadratic], ld.refused) for ld in result.lift_drag]
    uri = fg.encode(force_flow_figure(result), fmt) if rows else ""
    caption = ("Force on the held vehicle (its zero at each angle removed) against the flow "
               "component along the axis, points with 95 % bars coloured by angle, and the "
               "fitted law F = F_lin nu + F_quad nu|nu|.")
    return CaptiveView(result.angle, rows, refused, lift_drag, uri, caption)
