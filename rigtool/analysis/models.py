"""The steady-state thruster model set for one depth: point selection, fits, residual spreads.

Forward (n > 0) and reverse (n < 0) points get their own C_p and C_i, fitted jointly with a
shared thrust zero (offset + linear drift, see fits.fit_directional); the current model uses
|n| from both directions. Points slower than max(min_speed_rpm, min_speed_frac * max|n|),
dead-zone points and points without a usable window are left out. The residual spreads
sigma_n (speed-based thrust) and sigma_i (current-based thrust, about the directly fitted
C_i) are given per point mean and per sample, after removing the fitted zero, for the
sensor-fusion model. Model coefficient intervals carry `rel_systematic` (sensor scale).
Points that carry no error of their own (table rows, means of a few samples) are weighted by
the scatter about a first fit, modelled as growing with the thrust (or current).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from rigtool.analysis.fits import (
    RPM_PER_RPS,
    Coefficient,
    DirectionalFit,
    ZeroLine,
    coefficient_correlation,
    derive_thrust_current,
    fit_current_exponent,
    fit_current_speed,
    fit_directional,
    fit_thrust_current,
    fit_thrust_speed,
    residual_spread,
    thrust_coefficient,
    widen,
    with_systematic,
)
from rigtool.analysis.steady import PointTable

DIRECTIONS = (("fwd", 1.0), ("rev", -1.0))
FAST_FRAC = 0.3  # "fast" points: |speed| above this fraction of the largest (9 % of thrust)
STOPPED_FRAC = 0.005  # slower than this fraction of the largest speed: propeller stopped
UNSIGNED_MAX_NEGATIVE = 0.05  # fewer fast points below zero than this: the feedback is unsigned
WRONG_SIGN_FRAC = 0.2  # signed feedback contradicting the thrust on more fast points: warn
COMMAND_SIDE_AGREE = 0.95  # the command side of neutral gives the direction when this consistent
SCATTER_ITERATIONS = 4  # reweighted fits of the scatter model of table rows
SCATTER_FLOOR = 1e-3  # no row's scatter variance below this x the mean (none noiseless)


@dataclass(frozen=True)
class FitParams:
    """Point selection for the model fits (recorded in calibration.json)."""

    min_speed_rpm: float = 20.0
    min_speed_frac: float = 0.05
    min_window: int = 10
    rel_systematic: float = 1e-3  # scale uncertainty of force and feedback, added to intervals


@dataclass
class WindowSamples:
    """Steady-window samples of one depth; `point` indexes rows of that depth's PointTable."""

    point: np.ndarray
    thrust_n: np.ndarray
    speed_rpm: np.ndarray
    current_a: np.ndarray


@dataclass
class ModelFits:
    """Coefficients of one depth, the points they used, and the thrust zero they found."""

    coefficients: dict[str, Coefficient] = field(default_factory=dict)
    used: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    zero: ZeroLine | None = None
    torque_zero: ZeroLine | None = None  # zero of the torque about the thrust axis
    speed_sign: str = "measured"  # or "inferred from command" / "inferred from thrust"
    warnings: list[str] = field(default_factory=list)


@dataclass
class SpeedSign:
    """Per-point direction of the propeller (+1, -1; 0 where unknown) and where it came from."""

    sign: np.ndarray
    source: str
    warnings: list[str]


def candidate_points(points: PointTable, params: FitParams) -> np.ndarray:
    """Points whose window is usable for any fit: status ok, not dead, enough samples.

    Enough is `min_window`, or one (a table row is a point mean already), or any number when
    most points are that short (a log that holds each command briefly: its points are used
    as point means, see `single_readings`).
    """
    ok = (points.status == "ok") & np.isfinite(points.thrust.mean) & ~points.dead
    return ok & ((points.n_window >= params.min_window) | (points.n_samples == 1)
                 | _short_log(points, ok, params))


def _short_log(points: PointTable, ok: np.ndarray, params: FitParams) -> bool:
    """True when most usable points have fewer than `min_window` samples in their window."""
    return bool(ok.any() and np.median(points.n_window[ok]) < params.min_window)


def speed_sign(points: PointTable, neutral_command: float, use: np.ndarray) -> SpeedSign:
    """The propeller's direction at each point.

    Signed feedback is kept (with a warning naming the columns when its sign contradicts the
    thrust on the fast points). Unsigned feedback (no fast point below zero while thrust takes
    both signs, as optical tachometers and manufacturer tables give it) takes its sign from
    the command's side of neutral, oriented by the thrust, or, where the command does not
    tell (both directions on one side, as on the STM32 bridge), from the sign of the thrust.
    Thrust is taken relative to the thrust with the propeller stopped (the sensor's zero).
    """
    n = points.speed.mean
    sign = np.sign(np.nan_to_num(n))
    ok = use & np.isfinite(n) & np.isfinite(points.thrust.mean)
    if not ok.any():
        return SpeedSign(sign, "measured", [])
    top = float(np.max(np.abs(n[ok])))
    f = points.thrust.mean - _stopped_thrust(points, ok, top)
    fast = ok & (np.abs(n) > FAST_FRAC * top) & (f != 0)
    if not fast.any():
        return SpeedSign(sign, "measured", [])
    thrust_sign = np.sign(f)
    if np.mean(n[fast] < 0) >= UNSIGNED_MAX_NEGATIVE or not (thrust_sign[fast] < 0).any():
        wrong = int(np.sum(sign[fast] != thrust_sign[fast]))
        warnings = []
        if wrong > WRONG_SIGN_FRAC * fast.sum():
            warnings.append(f"speed_rpm sign disagrees with thrust_n on {wrong} of "
                            f"{int(fast.sum())} fast points (check the sign convention of the "
                            "speed feedback or of the thrust axis)")
        return SpeedSign(sign, "measured", warnings)
    side = np.sign(points.command - neutral_command)
    sided = fast & (side != 0)
    orient = np.sign(np.sum(side[sided] * thrust_sign[sided])) if sided.any() else 0.0
    agree = np.mean(side[sided] * orient == thrust_sign[sided]) if sided.any() else 0.0
    if orient != 0 and agree >= COMMAND_SIDE_AGREE:
        inferred = np.where(side != 0, side * orient, thrust_sign)
        return SpeedSign(inferred, "inferred from command", [])
    return SpeedSign(thrust_sign, "inferred from thrust", [])


def single_readings(points: PointTable, params: FitParams) -> np.ndarray:
    """Points whose speed is one reading (a table row, even one stored as n samples of its
    mean and std) or a mean of too few samples to judge its error: only the scatter about
    the fit can tell their errors."""
    se = points.speed.se
    return ~(np.isfinite(se) & (se > 0)) | (points.n_window < params.min_window)


def scatter_se(pred: np.ndarray, resid: np.ndarray, se: np.ndarray) -> np.ndarray:
    """Standard errors that make the scatter about a first fit (`pred`, `resid`) their own:
    `se` plus what it does not explain, a + b |pred| + c pred^2 (absolute noise, speed noise,
    relative noise), so no point is weighted as if noiseless.

    The variance model is fitted to the squared residuals, reweighted by its own values (a
    squared residual scatters in proportion to its variance).
    """
    from scipy import optimize

    stated = np.nan_to_num(se) ** 2
    excess = resid**2 - stated
    design = np.column_stack([np.ones(pred.size), np.abs(pred), pred**2])
    var = np.full(pred.size, max(float(np.mean(np.maximum(excess, 0.0))), 0.0))
    if not var[0] > 0:
        return se
    for _ in range(SCATTER_ITERATIONS):
        a = design / var[:, None]
        norm = np.linalg.norm(a, axis=0)
        norm[norm == 0] = 1.0
        coef, _ = optimize.nnls(a / norm, excess / var)
        var = np.maximum(design @ (coef / norm), SCATTER_FLOOR * float(np.mean(var)))
    return np.sqrt(stated + var)


def _stopped_thrust(points: PointTable, ok: np.ndarray, top_rpm: float) -> float:
    """Median thrust where the propeller stands still (the sensor's zero; 0 without such
    points): the slow points' thrust is judged against it, not against a zero it may miss."""
    stopped = ok & (np.abs(points.speed.mean) <= STOPPED_FRAC * top_rpm)
    return float(np.median(points.thrust.mean[stopped])) if stopped.any() else 0.0


def fit_models(points: PointTable, samples: WindowSamples, *, diameter_m: float | None,
               density_kg_m3: float | None, params: FitParams | None = None,
               zero: ZeroLine | None = None, direction: SpeedSign | None = None) -> ModelFits:
    """All speed/current model coefficients of one depth.

    The thrust zero is fitted jointly with C_p unless `zero` is given (points that may be
    ventilating must not set the zero). `direction` gives unsigned speed feedback its sign
    (see `speed_sign`; default: the feedback as measured).
    """
    p = params or FitParams()
    use = candidate_points(points, p)
    result = ModelFits(used=np.zeros(len(points), dtype=bool))
    if not points.speed.measured:
        return result
    f, se_f, t = points.thrust.mean, points.thrust.se, points.t_mid_s
    n, se_n = points.speed.mean, points.speed.se
    n_s = samples.speed_rpm
    use &= np.isfinite(n)
    if not use.any():
        return result
    if direction is not None:
        result.speed_sign, result.warnings = direction.source, direction.warnings
        if direction.source != "measured":
            n = np.abs(n) * direction.sign
            n_s = np.abs(n_s) * direction.sign[samples.point]
    n_min = max(p.min_speed_rpm, p.min_speed_frac * float(np.max(np.abs(n[use]))))
    masks = {"fwd": use & (n > n_min), "rev": use & (n < -n_min)}
    thrust_fit = fit_thrust_speed(n, f, se_f, se_n, t, masks, zero)
    if thrust_fit is None:
        return result
    single = single_readings(points, p)
    if (single & thrust_fit.used).any():
        se_f = _scatter_weights(thrust_fit, se_f, single)
        thrust_fit = fit_thrust_speed(n, f, se_f, se_n, t, masks, zero) or thrust_fit
    out = result.coefficients
    cp = {}
    for key in ("fwd", "rev"):
        if key in thrust_fit.columns:
            cp[key] = with_systematic(thrust_fit.coefficient(
                key, f"C_p_{key}", "N/(r/min)^2", "f = C_p |n| n"), p.rel_systematic)
            out[cp[key].name] = cp[key]
            if diameter_m and density_kg_m3:
                out[f"K_T_{key}"] = thrust_coefficient(cp[key], diameter_m, density_kg_m3,
                                                       f"K_T_{key}")
    for c in thrust_fit.zero_coefficients():
        out[c.name] = c
    result.used = thrust_fit.used
    result.zero = thrust_fit.zero
    zero = result.zero.at(t)
    pred = _signed_model(cp, n, lambda c, v: c * np.abs(v) * v)
    pred_s = _signed_model(cp, n_s, lambda c, v: c * np.abs(v) * v, np.sign(n)[samples.point])
    in_fit = result.used[samples.point]
    out["sigma_n_point"] = residual_spread(
        (f - zero - pred)[result.used], "sigma_n_point",
        "RMS of point-mean thrust minus zero minus C_p |n| n", interval=True)
    out["sigma_n_sample"] = residual_spread(
        (samples.thrust_n - zero[samples.point] - pred_s)[in_fit], "sigma_n_sample",
        "RMS of sample thrust minus zero minus C_p |n| n over the steady windows; no interval "
        "(samples are autocorrelated)", interval=False)
    if points.torque.measured:
        out.update(_torque_models(points, n, se_n, t, masks, result, diameter_m,
                                  density_kg_m3, p))
    if points.current.measured:
        weighted = _current_scatter_weights(points, n, single & result.used)
        out.update(_current_models(weighted, samples, n, masks, thrust_fit, cp, p))
    return result


def _torque_models(points: PointTable, n: np.ndarray, se_n: np.ndarray, t: np.ndarray,
                   masks: dict[str, np.ndarray], result: ModelFits, diameter_m: float | None,
                   density_kg_m3: float | None, p: FitParams) -> dict[str, Coefficient]:
    """Q = C_q |n| n per direction about the thrust axis, with its own zero and drift, and
    K_Q = |Q| / (rho n^2 D^5) where diameter and density are known."""
    q, se_q = points.torque.mean, points.torque.se
    ok = np.isfinite(q) & np.isfinite(se_q)
    fit = fit_directional(np.abs(n) * n, np.where(ok, q, 0.0), np.where(ok, se_q, np.inf),
                          None if se_n is None else 2 * np.abs(n) * se_n, t,
                          {k: m & ok for k, m in masks.items()})
    if fit is None:
        return {}
    result.torque_zero = fit.zero
    out = {}
    for key in ("fwd", "rev"):
        if key not in fit.columns:
            continue
        c = fit.coefficient(key, f"C_q_{key}", "N m/(r/min)^2",
                            "Q = C_q |n| n, torque about the thrust axis (sign: right-hand "
                            "rule about forward thrust)")
        c = with_systematic(dataclasses.replace(c, rms_unit="N m"), p.rel_systematic)
        out[c.name] = c
        if diameter_m and density_kg_m3:
            k = RPM_PER_RPS**2 / (density_kg_m3 * diameter_m**5)
            lo, hi = sorted((abs(c.lo) * k, abs(c.hi) * k)) if c.lo * c.hi > 0 else (
                0.0, max(abs(c.lo), abs(c.hi)) * k)
            out[f"K_Q_{key}"] = Coefficient(
                f"K_Q_{key}", abs(c.value) * k, lo, hi, "1", c.n, c.r2, c.rms, "N m",
                f"K_Q = |C_q| * 3600 / (rho D^5), D = {diameter_m:g} m, "
                f"rho = {density_kg_m3:g} kg/m^3")
    return out


def _scatter_weights(fit: DirectionalFit, se: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """`se` of the fitted points among `rows` replaced by `scatter_se` of their residuals."""
    used = np.flatnonzero(fit.used)
    pick = rows[used]
    out = np.array(se, dtype=float)
    out[used[pick]] = scatter_se((fit.y - fit.fit.resid)[pick], fit.fit.resid[pick],
                                 se[used[pick]])
    return out


def _current_scatter_weights(points: PointTable, n: np.ndarray, rows: np.ndarray) -> PointTable:
    """`points` with the current SE at `rows` (one reading each) from the scatter about a
    first I = C_n |n|^3 + I_0 fit, so C_n weighs table rows by their noise, not equally."""
    cur = points.current
    m = rows & np.isfinite(cur.mean)
    if m.sum() < 4:
        return points
    i_abs = np.abs(cur.mean[m])
    fit = fit_current_speed(n[m], i_abs, cur.se[m], None)[2]
    se = cur.se.copy()
    se[m] = scatter_se(i_abs - fit.resid, fit.resid, cur.se[m])
    return dataclasses.replace(points, current=dataclasses.replace(cur, se=se))


def _signed_model(coef: dict[str, Coefficient], x: np.ndarray,
                  model: Callable[[float, np.ndarray], np.ndarray],
                  sign: np.ndarray | None = None) -> np.ndarray:
    """model(C_dir, x) with C_dir chosen by the sign of each point (or of `sign`)."""
    s = np.sign(x) if sign is None else sign
    out = np.zeros(x.size)
    for key, direction in DIRECTIONS:
        if key in coef:
            out += np.where(s == direction, model(coef[key].value, x), 0.0)
    return out


def _current_models(points: PointTable, samples: WindowSamples, n: np.ndarray,
                    masks: dict[str, np.ndarray], thrust_fit: DirectionalFit,
                    cp: dict[str, Coefficient], p: FitParams) -> dict[str, Coefficient]:
    used, zero_line = thrust_fit.used, thrust_fit.zero
    cur, se_i = points.current.mean, points.current.se
    cur_s = samples.current_a
    m = used & np.isfinite(cur)
    if m.sum() < 3:
        return {}
    if (m & (n < 0)).any() and np.median(cur[m & (n < 0)]) < 0:
        # The driver reports signed current: the model is in its magnitude.
        cur, cur_s = np.abs(cur), np.abs(cur_s)
    out: dict[str, Coefficient] = {}
    c_n, i_0, cn_fit = fit_current_speed(n[m], cur[m], se_i[m], points.speed.se[m],
                                         points.t_mid_s[m])
    c_n = with_systematic(c_n, p.rel_systematic)
    out["C_n"], out["I_0"] = c_n, i_0
    if m.sum() >= 4:
        try:
            for c in fit_current_exponent(n[m], cur[m], se_i[m], c_n.value, i_0.value):
                out[c.name] = with_systematic(c, p.rel_systematic) if c.name == "C_free" else c
        except (RuntimeError, ValueError):
            pass
    for key in cp:
        rho = coefficient_correlation(thrust_fit.fit, thrust_fit.columns.index(key),
                                      np.flatnonzero(used), cn_fit, 0, np.flatnonzero(m))
        out[f"C_i_{key}"] = with_systematic(
            derive_thrust_current(cp[key], c_n, f"C_i_{key}", rho), p.rel_systematic)
    cur_masks = {k: v & m for k, v in masks.items()}
    se_i0 = (i_0.hi - i_0.lo) / 2 / 1.96 if np.isfinite(i_0.hi - i_0.lo) else 0.0

    def direct_fit(i0: float, zero: ZeroLine) -> DirectionalFit | None:
        return fit_thrust_current(cur, i0, points.thrust.mean, points.thrust.se, se_i,
                                  points.t_mid_s, cur_masks, zero, se_i0)

    direct = direct_fit(i_0.value, zero_line)
    if direct is None:
        return out
    shared = _shared_error_spread(direct, direct_fit, i_0.value, se_i0, zero_line)
    ci = {}
    for key in ("fwd", "rev"):
        if key in direct.columns:
            c = widen(direct.coefficient(
                key, f"C_i_{key}_direct", "N/A^(2/3)",
                "fitted directly: f = C_i (I - I_0)^(2/3)"), shared.get(key, 0.0))
            ci[key] = with_systematic(c, p.rel_systematic)
            out[ci[key].name] = ci[key]
    zero = direct.zero.at(points.t_mid_s)

    def model(c: float, v: np.ndarray) -> np.ndarray:
        return c * np.maximum(v - i_0.value, 0.0) ** (2 / 3)

    sign = np.sign(n)
    pred = _signed_model(ci, cur, model, sign) * sign
    pred_s = _signed_model(ci, cur_s, model, sign[samples.point]) * sign[samples.point]
    in_fit = direct.used[samples.point] & np.isfinite(cur_s)
    f = points.thrust.mean
    out["sigma_i_point"] = residual_spread(
        (f - zero - pred)[direct.used], "sigma_i_point",
        "RMS of point-mean thrust minus zero minus C_i_direct (I - I_0)^(2/3)", interval=True)
    out["sigma_i_sample"] = residual_spread(
        (samples.thrust_n - zero[samples.point] - pred_s)[in_fit], "sigma_i_sample",
        "RMS of sample thrust minus zero minus C_i_direct (I - I_0)^(2/3) over the steady "
        "windows; no interval (samples are autocorrelated)", interval=False)
    return out


def _shared_error_spread(direct: DirectionalFit,
                         refit: Callable[[float, ZeroLine], DirectionalFit | None],
                         i_0: float, se_i0: float, zero: ZeroLine) -> dict[str, float]:
    """Standard error each direct C_i gets from errors every point shares: the idle current
    I_0 and the thrust zero's offset and drift (refits at +-1 SE of each; the point scatter
    cannot show them)."""
    cov = zero.cov or ((0.0, 0.0), (0.0, 0.0))
    sd_offset, sd_drift = math.sqrt(max(cov[0][0], 0.0)), math.sqrt(max(cov[1][1], 0.0))
    var = dict.fromkeys(direct.columns, 0.0)
    for d_i0, d_offset, d_drift in ((se_i0, 0.0, 0.0), (0.0, sd_offset, 0.0),
                                    (0.0, 0.0, sd_drift)):
        if d_i0 == d_offset == d_drift == 0.0:
            continue
        up = refit(i_0 + d_i0, dataclasses.replace(
            zero, offset_n=zero.offset_n + d_offset, drift_n_per_s=zero.drift_n_per_s + d_drift))
        down = refit(i_0 - d_i0, dataclasses.replace(
            zero, offset_n=zero.offset_n - d_offset, drift_n_per_s=zero.drift_n_per_s - d_drift))
        if up is None or down is None or not up.columns == down.columns == direct.columns:
            continue
        for k, a, b in zip(direct.columns, up.fit.beta, down.fit.beta, strict=True):
            var[k] += ((a - b) / 2) ** 2
    return {k: math.sqrt(v) for k, v in var.items()}
