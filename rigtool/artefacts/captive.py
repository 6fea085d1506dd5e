"""The captive section of calibration.json and captive.csv: a held vehicle's damping laws
(docs/vehicle.md)."""

from __future__ import annotations

from collections.abc import Callable, Iterable

from rigtool.analysis.captive import FORCES, CaptiveResult
from rigtool.analysis.fits import Coefficient

CAPTIVE_FILE = "captive.csv"
CAPTIVE_COLUMNS = (("step_idx", "", "plan index of the point"),
                   ("speed_mps", "m/s", "flow or tow speed as the carriage reported it"),
                   ("angle_deg", "deg", "yaw or attack angle of the held vehicle"),
                   ("u_mps", "m/s", "flow along the body x axis"),
                   ("v_mps", "m/s", "flow along the body y axis"),
                   ("w_mps", "m/s", "flow along the body z axis"),
                   *((f"{f}_mean", "N" if i < 3 else "N m", f"mean {f} over the point")
                     for i, f in enumerate(FORCES)),
                   *((f"{f}_se", "N" if i < 3 else "N m", f"standard error of {f}_mean")
                     for i, f in enumerate(FORCES)))
CAPTIVE_DOC = ["captive run: per point the flow it was held in and the mean of each F/T "
               "channel (body axes after the rig's mount transform)"]

CoefDoc = Callable[[Coefficient], dict]


def captive_doc(result: CaptiveResult, coef: CoefDoc) -> dict:
    """The `captive` section: per axis its law or the reason it is refused, lift and drag per
    angle, the warnings."""
    def opt(c: Coefficient | None) -> dict | None:
        """A coefficient's document, or None where refused."""
        return None if c is None else coef(c)

    return {
        "angle": result.angle,
        "model": "per axis F = F_lin nu + F_quad nu|nu| (nu = u, v, w: the flow relative to "
                 "the body), weighted least squares pooled over the angles with a zero offset "
                 "per angle; drag and lift per angle as D = D_U U + D_UU U|U|",
        "n_points": int(result.points.step_idx.size),
        "speeds_mps": sorted({float(v) for v in result.points.speed_mps}),
        "angles_deg": sorted({float(v) for v in result.points.angle_deg}),
        "laws": {law.force: {"velocity": law.velocity, "linear": opt(law.linear),
                             "quadratic": opt(law.quadratic), "zero_drift": opt(law.drift),
                             "zero_per_angle_n": dict(zip(
                                 (f"{a:g}" for a in law.offset_angles_deg),
                                 (float(v) for v in law.offsets), strict=True)),
                             "refused": law.refused or None}
                 for law in result.laws},
        "lift_drag": [{"angle_deg": ld.angle_deg, "drag_linear": opt(ld.drag_linear),
                       "drag_quadratic": opt(ld.drag_quadratic),
                       "lift_linear": opt(ld.lift_linear),
                       "lift_quadratic": opt(ld.lift_quadratic), "refused": ld.refused or None}
                      for ld in result.lift_drag],
        "warnings": list(result.warnings),
        "file": CAPTIVE_FILE,
    }


def captive_rows(result: CaptiveResult) -> Iterable[list[object]]:
    """The rows of captive.csv, one per point."""
    p = result.points
    for i in range(p.step_idx.size):
        yield [int(p.step_idx[i]), p.speed_mps[i], p.angle_deg[i], *p.velocity_mps[i],
               *p.mean[i], *p.se[i]]
