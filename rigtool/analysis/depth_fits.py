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

The current law is I = C_n |n|^3 + I_0 unless the free exponent k (I = C |n|^k + I_0) is
further from 3 than LAW_Z standard errors and than LAW_MIN_DK: then a warning says so, and
C_i, sigma_i and the coefficient `current_exponent` carry that law (f = C_i (I - I_0_free)^(2/k),
C_i in N/A^(2/k), its interval including the error of k). C_i intervals are sandwiches over
every fit a point's error passes through (fits.sandwich_variance).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from rigtool.analysis.fits import (
    CUBIC,
    RPM_PER_RPS,
    SECONDS_PER_HOUR,
    Z95,
    Coefficient,
    DirectionalFit,
    LinearFit,
    Part,
    ZeroLine,
    current_law_influence,
    current_power_unit,
    derive_thrust_current,
    fit_current_exponent,
    fit_current_speed,
    fit_directional,
    fit_thrust_current,
    fit_thrust_speed,
    residual_spread,
    sandwich_variance,
    t95,
    thrust_coefficient,
    with_interval,
    with_systematic,
)
from rigtool.analysis.steady import PointTable
from rigtool.analysis.thrust_law import LOW_FRAC, choose_law
from rigtool.models import laws

DIRECTIONS = (("fwd", 1.0), ("rev", -1.0))
FAST_FRAC = 0.3  # "fast" points: |speed| above this fraction of the largest (9 % of thrust)
STOPPED_FRAC = 0.005  # slower than this fraction of the largest speed: propeller stopped
UNSIGNED_MAX_NEGATIVE = 0.05  # fewer fast points below zero than this: the feedback is unsigned
WRONG_SIGN_FRAC = 0.2  # signed feedback contradicting the thrust on more fast points: warn
COMMAND_SIDE_AGREE = 0.95  # the command side of neutral gives the direction when this consistent
SCATTER_ITERATIONS = 4  # reweighted fits of the scatter model of table rows
SCATTER_FLOOR = 1e-3  # no row's scatter variance below this x the mean (none noiseless)
LAW_Z = 3.29  # the free exponent replaces 3 when further from it than this many SEs (99.9 %)
LAW_MIN_DK = 0.05  # ... and than this: a smaller change moves C_i by < 3 % over 10:1 in current


@dataclass(frozen=True)
class FitParams:
    """Point selection for the model fits (recorded in calibration.json)."""

    min_speed_rpm: float = 20.0
    min_speed_frac: float = 0.05
    min_window: int = 10
    rel_systematic: float = 1e-3  # scale uncertainty of force and feedback, added to intervals


class SampleSpreads(Protocol):
    """The steady-window samples of one depth, as the per-sample spreads need them."""

    def spread(self, name: str, note: str,
               residual: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], np.ndarray]
               ) -> Coefficient:
        """RMS (no interval) of residual(point, thrust_n, speed_rpm, current_a) over the
        window samples; `point` indexes rows of the depth's PointTable."""


@dataclass
class ModelFits:
    """Coefficients of one depth, the points they used, and the thrust zero they found."""

    coefficients: dict[str, Coefficient] = field(default_factory=dict)
    used: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    zero: ZeroLine | None = None
    torque_zero: ZeroLine | None = None  # zero of the torque about the thrust axis
    speed_sign: str = "measured"  # or "inferred from command" / "inferred from thrust"
    warnings: list[str] = field(default_factory=list)
    thrust_law: dict[str, dict] = field(default_factory=dict)  # per direction: thrust_law.py


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


def fit_models(points: PointTable, samples: SampleSpreads, *, diameter_m: float | None,
               density_kg_m3: float | None, params: FitParams | None = None,
               zero: ZeroLine | None = None, direction: SpeedSign | None = None,
               sessions: tuple[float, ...] = (), drift: bool = True) -> ModelFits:
    """All speed/current model coefficients of one depth.

    The thrust zero is fitted jointly with C_p unless `zero` is given (points that may be
    ventilating must not set the zero). `direction` gives unsigned speed feedback its sign
    (see `speed_sign`; default: the feedback as measured). `sessions` are the start times of
    a resumed run's later sessions: each has its own zero offset (and torque offset);
    `drift`: the design separates a zero drift from the law (drift_design.py).
    """
    p = params or FitParams()
    use = candidate_points(points, p)
    result = ModelFits(used=np.zeros(len(points), dtype=bool))
    if not points.speed.measured:
        return result
    f, se_f, t = points.thrust.mean, points.thrust.se, points.t_mid_s
    n, se_n = points.speed.mean, points.speed.se
    use &= np.isfinite(n)
    if not use.any():
        return result
    if direction is not None:
        result.speed_sign, result.warnings = direction.source, direction.warnings
        if direction.source != "measured":
            n = np.abs(n) * direction.sign
    n_min = max(p.min_speed_rpm, p.min_speed_frac * float(np.max(np.abs(n[use]))))
    masks = {"fwd": use & (n > n_min), "rev": use & (n < -n_min)}
    rate = points.speed_sq_rate if points.speed_sq_rate.size == n.size else None
    thrust_fit = fit_thrust_speed(n, f, se_f, se_n, t, masks, zero, sessions, drift, rate)
    if thrust_fit is None:
        return result
    single = single_readings(points, p)
    if (single & thrust_fit.used).any():
        se_f = _scatter_weights(thrust_fit, se_f, single)
        thrust_fit = (fit_thrust_speed(n, f, se_f, se_n, t, masks, zero, sessions, drift, rate)
                      or thrust_fit)
    out = result.coefficients
    cp = _thrust_coefficients(thrust_fit, out, p, diameter_m, density_kg_m3)
    for c in [*thrust_fit.zero_coefficients(), thrust_fit.lag_coefficient()]:
        if c is not None:
            out[c.name] = c
    result.used = thrust_fit.used
    result.zero = thrust_fit.zero
    zero = result.zero.at(t)
    result.thrust_law, laws_said = _thrust_laws(n, f - zero, se_f, masks, thrust_fit.used,
                                                result.zero.var_at(t))
    pred = _signed_model(cp, n, lambda c, v: laws.thrust_from_speed(v, c, c))
    inferred = direction is not None and direction.source != "measured"

    sign_n, used, zero_p = np.sign(n), result.used, zero
    sign_d = direction.sign if inferred else None

    def sample_residual(point: np.ndarray, thrust_n: np.ndarray, speed_rpm: np.ndarray,
                        _current_a: np.ndarray) -> np.ndarray:
        n_s = speed_rpm if sign_d is None else np.abs(speed_rpm) * sign_d[point]
        pred_s = _signed_model(cp, n_s, lambda c, v: laws.thrust_from_speed(v, c, c),
                               sign_n[point])
        return (thrust_n - zero_p[point] - pred_s)[used[point]]

    out["sigma_n_point"] = residual_spread(
        (f - zero - pred)[result.used], "sigma_n_point",
        "RMS of point-mean thrust minus zero minus C_p |n| n", interval=True)
    out["sigma_n_sample"] = samples.spread(
        "sigma_n_sample", "RMS of sample thrust minus zero minus C_p |n| n over the steady "
        "windows; no interval (samples are autocorrelated)", sample_residual)
    if points.torque.measured:
        out.update(_torque_models(points, n, se_n, t, masks, result, diameter_m,
                                  density_kg_m3, p, sessions, drift))
    if points.current.measured:
        weighted = _current_scatter_weights(points, n, single & result.used)
        coefs, warnings = _current_models(weighted, samples, n, masks, thrust_fit, cp, p,
                                          single)
        out.update(coefs)
        laws_said += warnings
    result.warnings = result.warnings + laws_said
    return result


def _thrust_coefficients(thrust_fit: DirectionalFit, out: dict[str, Coefficient], p: FitParams,
                         diameter_m: float | None, density_kg_m3: float | None
                         ) -> dict[str, Coefficient]:
    """C_p per direction fitted (and K_T where diameter and density are known), added to
    `out`; the C_p by direction key."""
    cp = {}
    for key in ("fwd", "rev"):
        if key in thrust_fit.columns:
            cp[key] = with_systematic(thrust_fit.coefficient(
                key, f"C_p_{key}", "N/(r/min)^2", "f = C_p |n| n"), p.rel_systematic)
            out[cp[key].name] = cp[key]
            if diameter_m and density_kg_m3:
                out[f"K_T_{key}"] = thrust_coefficient(cp[key], diameter_m, density_kg_m3,
                                                       f"K_T_{key}")
    return cp


def _thrust_laws(n: np.ndarray, f: np.ndarray, se_f: np.ndarray, masks: dict[str, np.ndarray],
                 used: np.ndarray, zero_var: np.ndarray) -> tuple[dict[str, dict], list[str]]:
    """Per direction, the thrust law the points follow (thrust_law.py), with `zero_var` the
    variance of the zero at each point, and a warning where C_p |n| n misses it by more than
    its allowance."""
    out, warnings = {}, []
    for key, word in (("fwd", "forward"), ("rev", "reverse")):
        m = masks[key] & used
        sd = math.sqrt(float(np.mean(zero_var[m]))) if m.any() else 0.0
        law = choose_law(n[m], f[m], se_f[m], sd) if m.any() else None
        if law is None:
            continue
        out[key] = law
        if not law["quadratic_adequate"]:
            warnings.append(
                f"thrust law ({word}): f = C_p |n| n misses the chosen law, {law['formula']}, "
                f"by up to {100 * law['quadratic_max_miss_frac']:.1f} % of full scale between "
                f"{100 * LOW_FRAC:g} and 100 % speed: use thrust_law in calibration.json "
                "(cal.thrust_from_speed evaluates it); a format that takes one coefficient "
                "carries that error")
    return out, warnings


def _torque_models(points: PointTable, n: np.ndarray, se_n: np.ndarray, t: np.ndarray,
                   masks: dict[str, np.ndarray], result: ModelFits, diameter_m: float | None,
                   density_kg_m3: float | None, p: FitParams,
                   sessions: tuple[float, ...] = (), drift: bool = True
                   ) -> dict[str, Coefficient]:
    """Q = C_q |n| n per direction about the thrust axis, with its own zero and drift (an
    offset per session), and K_Q = |Q| / (rho n^2 D^5) where diameter and density are known."""
    q, se_q = points.torque.mean, points.torque.se
    ok = np.isfinite(q) & np.isfinite(se_q)
    fit = fit_directional(np.abs(n) * n, np.where(ok, q, 0.0), np.where(ok, se_q, np.inf),
                          None if se_n is None else 2 * np.abs(n) * se_n, t,
                          {k: m & ok for k, m in masks.items()}, sessions=sessions,
                          drift=drift)
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
    first fit of I = C |n|^k + I_0 (k free, so a law that is not cubic leaves no misfit in
    the scatter), so the current fits weigh table rows by their noise, not equally."""
    cur = points.current
    m = rows & np.isfinite(cur.mean)
    if m.sum() < 4:
        return points
    i_abs = np.abs(cur.mean[m])
    c_n, i_0, fit = fit_current_speed(n[m], i_abs, cur.se[m], None)
    resid = fit.resid
    try:
        k, c, i0_free = fit_current_exponent(n[m], i_abs, cur.se[m], c_n.value, i_0.value)
        resid = i_abs - (c.value * np.abs(n[m]) ** k.value + i0_free.value)
    except (RuntimeError, ValueError):
        pass
    se = cur.se.copy()
    se[m] = scatter_se(i_abs - resid, resid, cur.se[m])
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


@dataclass
class CurrentLaw:
    """The current law current-based thrust uses, I = C |n|^k + I_0 (k = 3, or the free
    exponent when it excludes 3), and its fit: the point index of each fit row, the
    residuals (HC2-scaled), and the influence of each residual on log C, k (0 when k is
    held) and I_0."""

    k: float
    c: Coefficient
    i_0: Coefficient
    rows: np.ndarray
    resid: np.ndarray
    infl_log_c: np.ndarray
    infl_k: np.ndarray
    infl_i0: np.ndarray
    serial: tuple[float, float] = (1.0, 1.0)  # C's and I_0's LinearFit.serial
    dof: int = 10**6

    @classmethod
    def cubic(cls, c_n: Coefficient, i_0: Coefficient, fit: LinearFit,
              rows: np.ndarray) -> CurrentLaw:
        """I = C_n |n|^3 + I_0 from its linear fit."""
        return cls(CUBIC, c_n, i_0, rows, fit.hc2_resid, fit.influence[0] / c_n.value,
                   np.zeros(rows.size), fit.influence[1],
                   (float(fit.serial[0]), float(fit.serial[1])), fit.dof)

    @property
    def power(self) -> float:
        """The power of I - I_0 in f = C_i (I - I_0)^(2/k)."""
        return 2 / self.k

    @property
    def se_i0(self) -> float:
        """Standard error of I_0 (0 without an interval)."""
        hw = (self.i_0.hi - self.i_0.lo) / 2
        return hw / Z95 if math.isfinite(hw) else 0.0

    def log_ci_part(self) -> Part:
        """Error of log C^(2/k), the current fit's share of log C_i, from each residual."""
        log_c = math.log(self.c.value)
        infl = self.power * self.infl_log_c - 2 / self.k**2 * log_c * self.infl_k
        return self.rows, infl * self.resid * math.sqrt(self.serial[0])


def _current_models(points: PointTable, samples: SampleSpreads, n: np.ndarray,
                    masks: dict[str, np.ndarray], thrust_fit: DirectionalFit,
                    cp: dict[str, Coefficient], p: FitParams,
                    single: np.ndarray) -> tuple[dict[str, Coefficient], list[str]]:
    """C_n and I_0, the free-exponent law, C_i derived and direct, sigma_i; and the warning
    when the current law is not cubic."""
    cur, se_i = points.current.mean, points.current.se
    m = thrust_fit.used & np.isfinite(cur)
    if m.sum() < 3:
        return {}, []
    signed = bool((m & (n < 0)).any() and np.median(cur[m & (n < 0)]) < 0)
    if signed:
        cur = np.abs(cur)  # the driver reports signed current: the model is in its magnitude
    rows = np.flatnonzero(m)
    c_n, i_0, cn_fit = fit_current_speed(n[m], cur[m], se_i[m], points.speed.se[m],
                                         points.t_mid_s[m])
    out = {"C_n": with_systematic(c_n, p.rel_systematic), "I_0": i_0}
    out.update(_free_exponent(n[m], cur[m], se_i[m], c_n, i_0, p))
    law, warnings = CurrentLaw.cubic(c_n, i_0, cn_fit, rows), []
    if _excludes_cubic(out.get("k_free")):
        law = _free_law(n, cur, se_i, rows, out)
        out["current_exponent"] = dataclasses.replace(
            out["k_free"], name="current_exponent",
            note="exponent k of the current law C_i and sigma_i use: I = C_free |n|^k + "
                 "I_0_free (k_free, whose interval excludes 3)")
        warnings.append(_law_warning(out["k_free"], i_0))
    for key in cp:
        out[f"C_i_{key}"] = with_systematic(_derived_ci(cp[key], key, law, thrust_fit),
                                            p.rel_systematic)
    cur_masks = {k: v & m for k, v in masks.items()}
    direct = _direct_fit(points, cur, cur_masks, law, thrust_fit.zero, single)
    if direct is not None:
        ci = _direct_coefficients(direct, points, cur, law, thrust_fit, p)
        out.update({c.name: c for c in ci.values()})
        out.update(_current_spreads(points, samples, n, cur, ci, law, direct, signed))
    return out, warnings


def _free_exponent(n: np.ndarray, cur: np.ndarray, se: np.ndarray, c_n: Coefficient,
                   i_0: Coefficient, p: FitParams) -> dict[str, Coefficient]:
    """k_free, C_free and I_0_free of I = C |n|^k + I_0 (none when the fit fails)."""
    if n.size < 4:
        return {}
    try:
        fitted = fit_current_exponent(n, cur, se, c_n.value, i_0.value)
    except (RuntimeError, ValueError):
        return {}
    return {c.name: with_systematic(c, p.rel_systematic) if c.name == "C_free" else c
            for c in fitted}


def _excludes_cubic(k: Coefficient | None) -> bool:
    """True when the free exponent is further from 3 than LAW_Z of its standard errors and
    than LAW_MIN_DK (a significant difference that matters)."""
    if k is None or not (math.isfinite(k.lo) and math.isfinite(k.hi)):
        return False
    se = (k.hi - k.lo) / (2 * Z95)
    return se > 0 and abs(k.value - CUBIC) > max(LAW_Z * se, LAW_MIN_DK)


def _free_law(n: np.ndarray, cur: np.ndarray, se_i: np.ndarray, rows: np.ndarray,
              free: dict[str, Coefficient]) -> CurrentLaw:
    """The current law with the free exponent (k_free, C_free, I_0_free in `free`)."""
    k, c, i_0 = free["k_free"], free["C_free"], free["I_0_free"]
    resid, infl_c, infl_k, infl_i0 = current_law_influence(n[rows], cur[rows], se_i[rows],
                                                           c.value, k.value, i_0.value)
    return CurrentLaw(k.value, c, i_0, rows, resid, infl_c, infl_k, infl_i0,
                      dof=max(rows.size - 3, 1))


def _law_warning(k: Coefficient, i_0: Coefficient) -> str:
    """The warning that the cubic current law does not hold."""
    return (f"current law: I = C_n |n|^3 + I_0 does not fit this thruster (free exponent "
            f"k_free = {k.value:.2f}, 95 % {k.lo:.2f} .. {k.hi:.2f}, excludes 3; the cubic fit "
            f"gives I_0 = {i_0.value:.3g} A): C_i and sigma_i use I = C_free |n|^k + I_0_free, "
            "f = C_i (I - I_0_free)^(2/k), C_i in N/A^(2/k) (calibration.json current_law)")


def _derived_ci(cp: Coefficient, key: str, law: CurrentLaw,
                thrust_fit: DirectionalFit) -> Coefficient:
    """C_i = C_p / C^(2/k); its interval a sandwich over the points of both fits (a point's
    speed error moves C_p and C together and cancels in the ratio)."""
    c = derive_thrust_current(cp, law.c, f"C_i_{key}", exponent=law.k)
    if not math.isfinite(c.value):
        return c
    col = thrust_fit.columns.index(key)
    rows, law_part = law.log_ci_part()
    parts = [(np.flatnonzero(thrust_fit.used),
              _serial_part(thrust_fit.fit, col) / cp.value), (rows, -law_part)]
    var, dof = sandwich_variance(parts, len(thrust_fit.columns))
    dof = min(dof, thrust_fit.fit.dof, law.dof)
    return with_interval(c, t95(dof) * c.value * math.sqrt(var))


def _serial_part(fit: LinearFit, col: int) -> np.ndarray:
    """A fit's influence on coefficient `col` times its HC2 residuals, scaled for the serial
    correlation of its errors (the AR(1) variance factor of that coefficient)."""
    return fit.influence[col] * fit.hc2_resid * math.sqrt(float(fit.serial[col]))


def _direct_fit(points: PointTable, cur: np.ndarray, cur_masks: dict[str, np.ndarray],
                law: CurrentLaw, zero: ZeroLine, single: np.ndarray) -> DirectionalFit | None:
    """f = +-C_i (I - I_0)^(2/k) against the C_p fit's zero; points that are one reading each
    are weighted by the scatter about a first fit."""
    def run(se_f: np.ndarray) -> DirectionalFit | None:
        return fit_thrust_current(cur, law.i_0.value, points.thrust.mean, se_f,
                                  points.current.se, points.t_mid_s, cur_masks, zero,
                                  law.se_i0, law.power)

    direct = run(points.thrust.se)
    if direct is None or not (single & direct.used).any():
        return direct
    return run(_scatter_weights(direct, points.thrust.se, single)) or direct


def _direct_coefficients(direct: DirectionalFit, points: PointTable, cur: np.ndarray,
                         law: CurrentLaw, thrust_fit: DirectionalFit,
                         p: FitParams) -> dict[str, Coefficient]:
    """C_i_fwd_direct and C_i_rev_direct with intervals from every path a point's error takes
    into them (see `_direct_parts`)."""
    out = {}
    note = ("fitted directly: f = C_i (I - I_0)^(2/3)" if law.k == CUBIC else
            f"fitted directly: f = C_i (I - I_0_free)^(2/k), k = {law.k:.4g}")
    for key in ("fwd", "rev"):
        if key not in direct.columns:
            continue
        c = direct.coefficient(key, f"C_i_{key}_direct", current_power_unit(law.k), note)
        var, dof = sandwich_variance(_direct_parts(key, direct, points, cur, law, thrust_fit),
                                     len(direct.columns))
        dof = min(dof, direct.fit.dof)
        var += _fixed_zero_variance(direct, key, points.t_mid_s, thrust_fit)
        out[key] = with_systematic(with_interval(c, t95(dof) * math.sqrt(var)),
                                   p.rel_systematic)
    return out


def _direct_parts(key: str, direct: DirectionalFit, points: PointTable, cur: np.ndarray,
                  law: CurrentLaw, thrust_fit: DirectionalFit) -> list[Part]:
    """Error paths into a direct C_i: each point's own residual; the thrust zero the C_p fit
    set (its offset and drift, from the thrust residuals there); I_0, from the current
    residuals of the current fit."""
    col = direct.columns.index(key)
    rows = np.flatnonzero(direct.used)
    infl = direct.fit.influence[col]
    parts = [(rows, _serial_part(direct.fit, col))]
    if thrust_fit.fixed_zero is None:
        cols, fit = thrust_fit.columns, thrust_fit.fit
        hours = (points.t_mid_s[rows] - thrust_fit.t_ref_s) / SECONDS_PER_HOUR
        zero = _offset_parts(thrust_fit, infl, points.t_mid_s[rows])
        if "drift" in cols:
            zero = zero + float(np.sum(infl * hours)) * _serial_part(fit, cols.index("drift"))
        parts.append((np.flatnonzero(thrust_fit.used), -zero))
    beta = sum(np.where(direct.masks[k][rows], direct.fit.beta[i], 0.0)
               for i, k in enumerate(direct.columns))
    side = np.where(direct.masks.get("rev", np.zeros(len(points), bool))[rows], -1.0, 1.0)
    d = np.maximum(cur[rows] - law.i_0.value, 1e-12)
    slope = infl * side * beta * d**law.power  # d C_i / d x, times x
    grad_i0 = float(np.sum(slope * law.power / d))
    grad_k = float(np.sum(slope * np.log(d))) * 2 / law.k**2
    idle = grad_i0 * law.infl_i0 * math.sqrt(law.serial[1]) + grad_k * law.infl_k
    parts.append((law.rows, idle * law.resid))
    return parts


def _offset_parts(thrust_fit: DirectionalFit, infl: np.ndarray, t_s: np.ndarray) -> np.ndarray:
    """The error the thrust fit's zero offsets pass on through `infl` (per point at times
    `t_s`): each session's offset weighted by the influence of that session's points."""
    fit = thrust_fit.fit
    if not thrust_fit.session_starts:
        return float(np.sum(infl)) * _serial_part(fit, thrust_fit.columns.index("offset"))
    k = thrust_fit.zero.session_of(t_s)
    return sum(float(np.sum(infl[k == j])) * _serial_part(fit, col)
               for j, col in enumerate(thrust_fit.offset_columns))


def _fixed_zero_variance(direct: DirectionalFit, key: str, t_s: np.ndarray,
                         thrust_fit: DirectionalFit) -> float:
    """Variance a direct C_i gets from a zero given to the fits (shallow depths: from dead
    points or tares), from that zero's covariance."""
    zero = thrust_fit.fixed_zero
    if zero is None or zero.cov is None:
        return 0.0
    rows = np.flatnonzero(direct.used)
    infl = direct.fit.influence[direct.columns.index(key)]
    if zero.session_starts_s:
        if zero.session_cov is None:
            return 0.0
        k = zero.session_of(t_s[rows])
        grad = np.array([float(np.sum(infl[k == j])) for j in range(zero.offsets.size)]
                        + [float(np.sum(infl * (t_s[rows] - zero.t_ref_s)))])
        return max(float(grad @ np.array(zero.session_cov) @ grad), 0.0)
    a, b = float(np.sum(infl)), float(np.sum(infl * (t_s[rows] - zero.t_ref_s)))
    (c00, c01), (_, c11) = zero.cov
    return max(a * a * c00 + 2 * a * b * c01 + b * b * c11, 0.0)


def _current_spreads(points: PointTable, samples: SampleSpreads, n: np.ndarray,
                     cur: np.ndarray, ci: dict[str, Coefficient], law: CurrentLaw,
                     direct: DirectionalFit, signed: bool) -> dict[str, Coefficient]:
    """sigma_i per point mean and per sample: thrust minus zero minus the direct C_i law."""
    zero = direct.zero.at(points.t_mid_s)

    def model(c: float, v: np.ndarray) -> np.ndarray:
        return c * np.maximum(v - law.i_0.value, 0.0) ** law.power

    sign = np.sign(n)
    pred = _signed_model(ci, cur, model, sign) * sign

    def sample_residual(point: np.ndarray, thrust_n: np.ndarray, _speed_rpm: np.ndarray,
                        current_a: np.ndarray) -> np.ndarray:
        cur_s = np.abs(current_a) if signed else current_a
        pred_s = _signed_model(ci, cur_s, model, sign[point]) * sign[point]
        in_fit = direct.used[point] & np.isfinite(cur_s)
        return (thrust_n - zero[point] - pred_s)[in_fit]

    f = points.thrust.mean
    law_text = "(I - I_0)^(2/3)" if law.k == CUBIC else "(I - I_0_free)^(2/k)"
    return {
        "sigma_i_point": residual_spread(
            (f - zero - pred)[direct.used], "sigma_i_point",
            f"RMS of point-mean thrust minus zero minus C_i_direct {law_text}", interval=True),
        "sigma_i_sample": samples.spread(
            "sigma_i_sample", f"RMS of sample thrust minus zero minus C_i_direct {law_text} "
            "over the steady windows; no interval (samples are autocorrelated)",
            sample_residual)}
