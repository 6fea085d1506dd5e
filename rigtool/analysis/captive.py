"""Captive runs: the damping laws of a held vehicle from its forces in a flow or tow
([Fossen2011]; docs/vehicle.md).

Per point, the mean of each F/T channel and its standard error (autocorrelation counted, as
for thrust: steady.point_channel_stats). The flow relative to the body is u = U cos(angle)
and, by the angle swept, v = U sin(yaw) or w = U sin(attack). Per translational axis the law
X = X_u u + X_uu u|u| is fitted by weighted least squares (fits.wls: excess scatter, serial
correlation in acquisition order and lack of fit widen the interval), pooled over every
angle, with nuisance terms for the zero: one offset per angle (the sensor's zero, and the
held vehicle's weight and buoyancy, which turn with an angle of attack) and one linear drift
in time (the sensor's zero drifts after the tare; speeds visited in a monotone order would
otherwise turn that drift into a linear damping term). The law's two terms are
told apart only where the flow component took both signs (its offset is even in the flow, the
law odd) and at least two speed magnitudes (at one, u and u|u| are proportional); otherwise
the coefficient is refused with the reason, never given a number. Where an angle was swept,
drag (against the flow) and lift (across it, in the plane the angle turns in) are fitted
per angle as D = D_U U + D_UU U|U| the same way. Rotational damping (K_p, M_q, N_r) needs a
rotation rate, which a captive tow never has: it is refused.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from rigtool.analysis.dataset import CaptiveData
from rigtool.analysis.fits import Coefficient, fitted, wls
from rigtool.analysis.steady import point_channel_stats

FORCES = ("X", "Y", "Z", "K", "M", "N")
VELOCITIES = ("u", "v", "w")
SECONDS_PER_HOUR = 3600.0
ZERO_FLOW_FRAC = 1e-3  # a component below this fraction of the fastest flow counts as none
LINEAR_UNIT, QUADRATIC_UNIT = "N s/m", "N s^2/m^2"
ROTATION_REFUSED = ("K_p, K_pp, M_q, M_qq, N_r and N_rr are not identified: rotational "
                    "damping needs a rotation rate (a rotating arm or a planar motion "
                    "mechanism); a captive tow holds the vehicle still")


@dataclass
class CaptivePoints:
    """Per point: the flow (speed, angle, body components) and each channel's mean and
    standard error (columns X, Y, Z, K, M, N: N and N m)."""

    step_idx: np.ndarray
    speed_mps: np.ndarray
    angle_deg: np.ndarray
    velocity_mps: np.ndarray  # (n, 3): u, v, w
    mean: np.ndarray  # (n, 6)
    se: np.ndarray  # (n, 6)
    t_s: np.ndarray = field(default_factory=lambda: np.empty(0))  # mean time of each point


@dataclass
class CaptiveLaw:
    """One axis's damping law, or why the run cannot give it (`refused`)."""

    force: str  # "X", "Y", "Z"
    velocity: str  # "u", "v", "w"
    linear: Coefficient | None
    quadratic: Coefficient | None
    refused: str = ""
    offset_angles_deg: np.ndarray = field(default_factory=lambda: np.empty(0))
    offsets: np.ndarray = field(default_factory=lambda: np.empty(0))  # zero per angle (N)
    drift: Coefficient | None = None  # the zero's drift over the run (N/h), a nuisance term


@dataclass
class LiftDrag:
    """Drag and lift against the flow speed at one angle (laws of U), or why not."""

    angle_deg: float
    drag_linear: Coefficient | None
    drag_quadratic: Coefficient | None
    lift_linear: Coefficient | None
    lift_quadratic: Coefficient | None
    refused: str = ""


@dataclass
class CaptiveResult:
    """What a captive run gives: the points, the laws per axis, lift and drag per angle."""

    angle: str  # "yaw" or "attack"
    points: CaptivePoints
    laws: list[CaptiveLaw]
    lift_drag: list[LiftDrag]
    warnings: list[str]


def body_components(speed_mps: np.ndarray, angle_deg: np.ndarray, angle: str) -> np.ndarray:
    """(n, 3) flow relative to the body: u = U cos a, and U sin a on v (yaw) or w (attack)."""
    rad = np.radians(angle_deg)
    across = speed_mps * np.sin(rad)
    zero = np.zeros_like(across)
    return np.column_stack([speed_mps * np.cos(rad), *((across, zero) if angle == "yaw"
                                                        else (zero, across))])


def captive_points(data: CaptiveData) -> CaptivePoints:
    """Per-point means and standard errors of the six channels."""
    stats = [point_channel_stats(data.ft[:, k], data.offsets, "N" if k < 3 else "N m")
             for k in range(6)]
    return CaptivePoints(data.step_idx, data.speed_mps, data.angle_deg,
                         body_components(data.speed_mps, data.angle_deg, data.angle),
                         np.column_stack([s.mean for s in stats]),
                         np.column_stack([s.se for s in stats]), data.t_s)


def separable(nu: np.ndarray, names: str, scale: float, reversing: str) -> str:
    """Why a law in `nu` cannot be fitted ('' when it can): no such component, one sign
    only, or one magnitude only."""
    tol = ZERO_FLOW_FRAC * scale
    if not (np.abs(nu) > tol).any():
        return f"{names} are not identified: the flow never had this component ({reversing})"
    if not ((nu > tol).any() and (nu < -tol).any()):
        return f"{names} cannot be told apart: the flow never reversed"
    if len(np.unique(np.round(np.abs(nu[np.abs(nu) > tol]) / tol))) < 2:
        return (f"{names} cannot be told apart: the flow had one speed magnitude (the linear "
                "and quadratic terms are then proportional)")
    return ""


def smooth_errors(se: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The points' standard errors as a straight line in |y| fitted to them (a flow's
    unsteadiness grows with the load, over a floor): weights from each point's own noisy
    estimate would let chance decide which points count, and make the intervals too narrow."""
    ok = np.isfinite(se) & (se > 0) & np.isfinite(y)
    if ok.sum() < 3:
        return np.where(ok, se, np.nanmedian(se[ok]) if ok.any() else 1.0)
    slope, floor = np.polyfit(np.abs(y[ok]), se[ok], 1)
    line = floor + slope * np.abs(y)
    least = 0.25 * float(np.median(se[ok]))  # a line through or below zero: keep a floor
    return np.maximum(np.where(np.isfinite(line), line, least), least)


def _law_fit(nu: np.ndarray, y: np.ndarray, se: np.ndarray, groups: np.ndarray,
             order: np.ndarray, t_s: np.ndarray) -> tuple:
    """Weighted fit of y = offset[group] + drift t + a nu + b nu|nu| (the law's terms are the
    last two columns): (fit, offsets, refusal)."""
    levels = np.unique(groups)
    hours = (t_s - np.mean(t_s)) / SECONDS_PER_HOUR
    design = np.column_stack([(groups == g).astype(float) for g in levels]
                             + [hours, nu, nu * np.abs(nu)])
    if len(y) - design.shape[1] < 1:
        return None, levels, "too few points for the law and its zero offsets"
    sigma = smooth_errors(se, y)
    return wls(design, y, sigma, order=order, scale_down=True, lack_of_fit=True), levels, ""


def fit_law(points: CaptivePoints, k: int, angle_kind: str) -> CaptiveLaw:
    """The damping law of translational axis `k` (0 X, 1 Y, 2 Z), or its refusal."""
    force, vel = FORCES[k], VELOCITIES[k]
    names = f"{force}_{vel} and {force}_{vel}{vel}"
    hint = {0: "sweep speeds of both signs", 1: "sweep a yaw angle", 2: "sweep an angle of attack"}
    nu, y = points.velocity_mps[:, k], points.mean[:, k]
    why = separable(nu, names, float(np.max(np.abs(points.speed_mps))), hint[k])
    if why:
        return CaptiveLaw(force, vel, None, None, why)
    fit, levels, why = _law_fit(nu, y, points.se[:, k], points.angle_deg,
                                points.step_idx.astype(float), points.t_s)
    if fit is None:
        return CaptiveLaw(force, vel, None, None, f"{names}: {why}")
    p = len(levels) + 1
    note = (f"{force} = {force}_{vel} {vel} + {force}_{vel}{vel} {vel}|{vel}|, a zero per "
            "angle and a zero drift")
    return CaptiveLaw(
        force, vel,
        fitted(f"{force}_{vel}", fit, p, LINEAR_UNIT, y, "N", note),
        fitted(f"{force}_{vel}{vel}", fit, p + 1, QUADRATIC_UNIT, y, "N", note),
        "", levels.astype(float), np.asarray(fit.beta[:p - 1], dtype=float),
        fitted(f"{force}_zero_drift", fit, p - 1, "N/h", y, "N", "the zero's drift, fitted with "
               "the law"))


def flow_frame(points: CaptivePoints, angle_kind: str) -> tuple[np.ndarray, np.ndarray]:
    """(drag, lift) per point: the force against the flow's direction in the body, and across
    it in the plane the angle turns in (N)."""
    rad = np.radians(points.angle_deg)
    c, s = np.cos(rad), np.sin(rad)
    fx, across = points.mean[:, 0], points.mean[:, 1 if angle_kind == "yaw" else 2]
    return -(fx * c + across * s), -fx * s + across * c


def fit_lift_drag(points: CaptivePoints, angle_kind: str) -> list[LiftDrag]:
    """Drag and lift laws of the speed at each angle swept (none with one angle)."""
    angles = np.unique(points.angle_deg)
    if len(angles) < 2:
        return []
    drag, lift = flow_frame(points, angle_kind)
    rad = np.radians(points.angle_deg)
    se_x = points.se[:, 0]
    se_across = points.se[:, 1 if angle_kind == "yaw" else 2]
    se_drag = np.hypot(se_x * np.cos(rad), se_across * np.sin(rad))
    se_lift = np.hypot(se_x * np.sin(rad), se_across * np.cos(rad))
    out = []
    for a in angles:
        rows = points.angle_deg == a
        speed = points.speed_mps[rows]
        why = separable(speed, f"drag and lift at {a:g} deg", float(np.max(np.abs(speed))),
                        "sweep speeds of both signs")
        coefs: list[Coefficient | None] = [None] * 4
        for j, (y, se, name) in enumerate(((drag, se_drag, "D"), (lift, se_lift, "L"))):
            if why:
                break
            fit, _, why = _law_fit(speed, y[rows], se[rows], np.zeros(rows.sum()),
                                   points.step_idx[rows].astype(float), points.t_s[rows])
            if fit is not None:
                note = (f"{name} = {name}_U U + {name}_UU U|U| at {a:g} deg, a zero offset and "
                        "drift")
                coefs[2 * j] = fitted(f"{name}_U", fit, 2, LINEAR_UNIT, y[rows], "N", note)
                coefs[2 * j + 1] = fitted(f"{name}_UU", fit, 3, QUADRATIC_UNIT, y[rows], "N",
                                          note)
        out.append(LiftDrag(float(a), *coefs, why))
    return out


def fit_captive(data: CaptiveData) -> CaptiveResult:
    """Every law a captive run can give, and a warning for each it cannot."""
    points = captive_points(data)
    laws = [fit_law(points, k, data.angle) for k in range(3)]
    lift_drag = fit_lift_drag(points, data.angle)
    warnings = [f"captive: {law.refused}" for law in laws if law.refused]
    warnings += [f"captive: {ld.refused}" for ld in lift_drag if ld.refused]
    warnings += _drift_warning(laws[0], points)
    warnings.append(f"captive: {ROTATION_REFUSED}")
    return CaptiveResult(data.angle, points, laws, lift_drag, warnings)


def _drift_warning(law: CaptiveLaw, points: CaptivePoints) -> list[str]:
    """A warning when the zero of X drifted over the run (its interval clear of zero): the
    drift is fitted with the laws, but a tare between angles would remove it."""
    d = law.drift
    if d is None or d.lo <= 0 <= d.hi:
        return []
    span_h = float(np.ptp(points.t_s)) / SECONDS_PER_HOUR
    return [f"captive: the sensor's zero drifted at {d.value:.3g} N/h ({d.lo:.3g} .. "
            f"{d.hi:.3g}) on X over the run ({abs(d.value) * span_h:.3g} N); it is fitted "
            "with the laws, and a tare between angles would remove it"]


def truth_lift_drag(linear: tuple[float, ...], quadratic: tuple[float, ...], angle_deg: float,
                    angle_kind: str) -> tuple[float, float, float, float]:
    """(D_U, D_UU, L_U, L_UU) a diagonal damping model gives at one angle (for evaluation)."""
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    k = 1 if angle_kind == "yaw" else 2
    xl, xq, al, aq = linear[0], quadratic[0], linear[k], quadratic[k]
    drag_u = -(xl * c * c + al * s * s)
    drag_uu = -(xq * c * abs(c) * c + aq * s * abs(s) * s)
    lift_u = -xl * c * s + al * s * c
    lift_uu = -xq * c * abs(c) * s + aq * s * abs(s) * c
    return drag_u, drag_uu, lift_u, lift_uu
