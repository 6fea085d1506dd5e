"""Thruster dynamics from step responses: one-state and two-state models, fitted to thrust.

Speed is written in thrust units, s = sign(n) sqrt(C_p) |n| (so s|s| is the steady thrust,
and C_p cancels). After a command step the speed state follows its new target first order,
s' = (s_k - s) / tau_n; the two-state (Healey-type) model adds the axial inflow state m,
m' = (s - m) / tau_a, and thrust f = s|s| + g (s|s| - m|m|), which overshoots on a step while
the inflow builds up. The one-state model is g = 0. The command reaches the thruster `delay_s`
after it is sent (sensor-to-command delay). Both states are linear between steps, so the
response is evaluated in closed form on every sample (no ODE solver).

Fits are nonlinear least squares (scipy `least_squares`, bounded) over every sample of every
step, with the steady level of each command and the sensor zero as nuisance parameters. The
covariance is the largest of three estimates, each inflated for serially correlated
residuals (AR(1)): s^2 (J'J)^-1; the heteroscedasticity-consistent sandwich (thrust noise grows
with thrust, so the first alone is too narrow where the transients are large); and the
cluster-robust sandwich with one cluster per step, for a model that misses the same way
through a whole step (used with Student's t, one degree of freedom fewer than the steps).
Both models' information criteria use one effective sample size (from the two-state
residuals), so they differ only by the fit and the parameter count. The two-state model is
selected when its BIC is lower by more than BIC_MARGIN and its inflow gain is at least
MIN_GAIN with 95 % confidence that it is positive: a smaller gain changes a step response by
less than about that fraction of the step, which the one-state model describes as well.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from rigtool.analysis.fits import Coefficient

Z95 = 1.959963984540054
BIC_MARGIN = 10.0
MIN_GAIN = 0.01
TAIL_FRAC = 0.3  # last part of each hold taken as its steady level (starting values, metrics)
MIN_STEP_FRAC = 0.05  # steps smaller than this fraction of full scale get no timing metrics
BAND = 0.05  # settling band, fraction of the step


@dataclass(frozen=True)
class StepSeries:
    """The samples of a step-response run in time order, and when each level was commanded."""

    t_s: np.ndarray
    thrust_n: np.ndarray
    switch_s: np.ndarray  # command time of each level (run clock)
    command: np.ndarray  # command of each level
    neutral: float

    def level_of_sample(self) -> np.ndarray:
        return np.clip(np.searchsorted(self.switch_s, self.t_s, side="right") - 1, 0, None)


@dataclass
class DynamicsModel:
    """One fitted model: its parameters with 95 % intervals and its fit quality."""

    name: str  # "one-state" | "two-state"
    tau_n_s: Coefficient
    delay_s: Coefficient
    tau_a_s: Coefficient | None
    gain: Coefficient | None
    rms_n: float
    n_samples: int
    lag1_corr: float = 0.0  # lag-1 autocorrelation of the residuals
    n_params: int = 0  # (defaults: stored by an older rigtool, which kept only bic and aic)
    bic: float = math.nan  # set by identify, on an effective sample size common to both models
    aic: float = math.nan

    def params(self) -> tuple[float, float, float, float]:
        """(tau_n, tau_a, g, delay) for `response`."""
        tau_a = self.tau_a_s.value if self.tau_a_s else 1.0
        gain = self.gain.value if self.gain else 0.0
        return self.tau_n_s.value, tau_a, gain, self.delay_s.value


@dataclass
class StepMetrics:
    """Timing of one measured step (model-free): 10 % time, 10-90 % rise, 5 % settling."""

    command_from: float
    command_to: float
    thrust_from_n: float
    thrust_to_n: float
    direction: str  # "up" (|thrust| grows) | "down"
    t10_s: float
    rise_s: float
    settling_s: float
    overshoot_frac: float


@dataclass
class Dynamics:
    """Both models, the one the data support, and the measured step timings."""

    one_state: DynamicsModel
    two_state: DynamicsModel | None
    selected: str
    steps: list[StepMetrics]
    levels: dict[float, float]  # command -> fitted steady thrust (N)
    zero_n: float
    warnings: list[str] = field(default_factory=list)

    @property
    def model(self) -> DynamicsModel:
        return self.two_state if self.selected == "two-state" and self.two_state else self.one_state

    def fitted(self, series: StepSeries, model: DynamicsModel | None = None) -> np.ndarray:
        """The fitted thrust (N, with the sensor zero) on the series' samples."""
        m = model or self.model
        target = speed_target(np.array([self.levels.get(float(c), 0.0) for c in series.command]))
        return response(series.t_s, series.switch_s, target, *m.params()) + self.zero_n


def response(t_s: np.ndarray, switch_s: np.ndarray, target: np.ndarray, tau_n: float,
             tau_a: float, gain: float, delay: float, s0: float = 0.0,
             m0: float = 0.0) -> np.ndarray:
    """Thrust (N, without sensor zero) at times `t_s` after levels with speed targets
    `target` (thrust units, signed sqrt of the steady thrust) commanded at `switch_s`."""
    sw = np.asarray(switch_s, dtype=float) + delay
    tgt = np.asarray(target, dtype=float)
    ta = tau_a if abs(tau_a - tau_n) > 1e-6 * tau_n else tau_n * (1 + 1e-6)
    s_at, m_at = np.empty(sw.size), np.empty(sw.size)
    s, m = s0, m0
    for k in range(sw.size):  # states at each switch: one closed-form hop per level
        if k:
            s, m = _hop(s, m, tgt[k - 1], sw[k] - sw[k - 1], tau_n, ta)
        s_at[k], m_at[k] = s, m
    t = np.asarray(t_s, dtype=float)
    k = np.searchsorted(sw, t, side="right") - 1
    before = k < 0
    k = np.clip(k, 0, None)
    dt = np.where(before, 0.0, t - sw[k])
    s_t, m_t = _hop(s_at[k], m_at[k], tgt[k], dt, tau_n, ta)
    s_t = np.where(before, s0, s_t)
    m_t = np.where(before, m0, m_t)
    ss = s_t * np.abs(s_t)
    return ss + gain * (ss - m_t * np.abs(m_t))


def _hop(s, m, c, dt, tau_n: float, tau_a: float):
    """States after `dt` at target `c` (exact solution of the linear pair)."""
    e = s - c
    fast = np.exp(-dt / tau_n)
    a = e * tau_n / (tau_n - tau_a)
    return c + e * fast, c + a * fast + (m - c - a) * np.exp(-dt / tau_a)


def speed_target(thrust_n: np.ndarray | float) -> np.ndarray:
    """Signed square root: the speed state (thrust units) that holds `thrust_n` steadily."""
    f = np.asarray(thrust_n, dtype=float)
    return np.sign(f) * np.sqrt(np.abs(f))


def simulate(model: DynamicsModel, t_s: np.ndarray, command: np.ndarray,
             steady_thrust: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """Thrust (N) the model predicts for a command time series: `command[i]` holds from
    `t_s[i]`; `steady_thrust` maps a command to its steady thrust (e.g. `cal.thrust`)."""
    t = np.asarray(t_s, dtype=float)
    c = np.asarray(command, dtype=float)
    change = np.concatenate(([True], c[1:] != c[:-1]))
    target = speed_target(np.nan_to_num(np.asarray(steady_thrust(c[change]), dtype=float)))
    tau_n, tau_a, gain, delay = model.params()
    return response(t, t[change], target, tau_n, tau_a, gain, delay)


def identify(series: StepSeries, full_scale_n: float | None = None) -> Dynamics | None:
    """Fit both models to a step-response run; None when it holds fewer than two levels."""
    if series.switch_s.size < 2 or series.t_s.size < 20:
        return None
    level = series.level_of_sample()
    tails = _tail_means(series, level)
    neutral = np.isclose(series.command, series.neutral)
    zero = float(np.mean(tails[neutral])) if neutral.any() else 0.0
    commands = np.unique(series.command[~neutral])
    start_levels = {float(c): float(np.mean(tails[series.command == c]) - zero) for c in commands}
    tau0 = _first_time_constant(series, level, tails)
    one = _fit(series, commands, start_levels, zero, tau0, two_state=False)
    two = _fit(series, commands, start_levels, zero, tau0, two_state=True)
    n_eff = _effective_samples((two or one)[0])
    for fit in (one, two):
        if fit is not None:
            _set_criteria(fit[0], n_eff)
    best = one
    if (two is not None and two[0].bic < one[0].bic - BIC_MARGIN and two[0].gain.lo > 0
            and two[0].gain.value >= MIN_GAIN):
        best = two
    model, levels, zero_fit = best
    scale = full_scale_n or float(np.max(np.abs(tails - zero))) or 1.0
    steps = _step_metrics(series, level, tails - zero, zero, scale)
    warnings = []
    if model.rms_n > 0.05 * scale:
        warnings.append(f"dynamics: residual RMS {model.rms_n:.3g} N is above 5 % of full scale:"
                        " neither model describes these steps well")
    return Dynamics(one[0], two[0] if two else None, model.name, steps, levels, zero_fit,
                    warnings)


def _effective_samples(model: DynamicsModel) -> float:
    """Independent samples worth of the residuals, from their lag-1 autocorrelation."""
    r1 = model.lag1_corr
    return max(model.n_samples * (1 - r1) / (1 + r1), model.n_params + 1.0)


def _set_criteria(model: DynamicsModel, n_eff: float) -> None:
    """BIC and AIC of a Gaussian fit on `n_eff` effective samples."""
    fit = n_eff * math.log(max(model.rms_n, 1e-300) ** 2)
    model.bic = fit + model.n_params * math.log(n_eff)
    model.aic = fit + 2 * model.n_params


def _tail_means(series: StepSeries, level: np.ndarray) -> np.ndarray:
    out = np.full(series.switch_s.size, np.nan)
    for k in range(series.switch_s.size):
        f = series.thrust_n[level == k]
        if f.size:
            out[k] = float(np.mean(f[int(f.size * (1 - TAIL_FRAC)):]))
    return out


def _first_time_constant(series: StepSeries, level: np.ndarray, tails: np.ndarray) -> float:
    """Starting tau_n: time for the speed state to cover 63 % of the largest step."""
    jumps = np.abs(np.diff(speed_target(tails)))
    if not jumps.size or not np.isfinite(jumps).any():
        return 0.2
    k = int(np.nanargmax(jumps)) + 1
    pick = level == k
    s = speed_target(series.thrust_n[pick])
    a, b = speed_target(tails[k - 1]), speed_target(tails[k])
    frac = (s - a) / (b - a) if b != a else np.zeros_like(s)
    hit = np.flatnonzero(frac >= 0.632)
    t = series.t_s[pick]
    return float(max(t[hit[0]] - series.switch_s[k], 0.01)) if hit.size else 0.2


def _fit(series: StepSeries, commands: np.ndarray, start_levels: dict[float, float],
         zero: float, tau0: float, two_state: bool):
    from scipy.optimize import least_squares

    n_lv = commands.size
    level_idx = np.searchsorted(commands, series.command)
    is_neutral = np.isclose(series.command, series.neutral)
    dt = float(np.median(np.diff(series.t_s))) if series.t_s.size > 1 else 0.01

    def unpack(x):
        tau_n, delay = x[0], x[1]
        tau_a, gain = (x[2], x[3]) if two_state else (1.0, 0.0)
        lv = x[-(n_lv + 1):-1]
        f0 = x[-1]
        target = np.where(is_neutral, 0.0, speed_target(lv[np.clip(level_idx, 0, n_lv - 1)]))
        return tau_n, tau_a, gain, delay, lv, f0, target

    def resid(x):
        tau_n, tau_a, gain, delay, _, f0, target = unpack(x)
        return response(series.t_s, series.switch_s, target, tau_n, tau_a, gain,
                        delay) + f0 - series.thrust_n

    lv0 = [start_levels[float(c)] for c in commands]
    dyn0 = [tau0, dt] + ([tau0 * 2, 0.2] if two_state else [])
    lo = [1e-3, -0.1] + ([1e-3, 0.0] if two_state else []) + [-np.inf] * n_lv + [-np.inf]
    hi = [100.0, 10.0] + ([100.0, 10.0] if two_state else []) + [np.inf] * n_lv + [np.inf]
    x0 = np.clip(np.array(dyn0 + lv0 + [zero], dtype=float), np.array(lo) + 1e-9,
                 np.array(hi) - 1e-9)
    try:
        sol = least_squares(resid, x0, bounds=(lo, hi), x_scale="jac", method="trf")
    except ValueError:
        return None
    r = sol.fun
    n, p = r.size, sol.x.size
    rss = float(r @ r)
    s2 = rss / max(n - p, 1)
    r1 = float(np.sum(r[1:] * r[:-1]) / rss) if rss > 0 else 0.0
    r1 = min(max(r1, 0.0), 0.98)
    inflate = (1 + r1) / (1 - r1)
    jac = np.asarray(sol.jac)
    bread = np.linalg.pinv(jac.T @ jac)
    cov = bread * s2 * inflate
    score = np.zeros((series.switch_s.size, p))
    np.add.at(score, series.level_of_sample(), jac * r[:, None])
    clustered = bread @ (score.T @ score) @ bread
    jr = jac * r[:, None]
    cov = np.maximum(cov, bread @ (jr.T @ jr) @ bread * inflate)
    n_clusters = series.switch_s.size
    from scipy import special

    t_crit = float(special.stdtrit(max(n_clusters - 1, 1), 0.975))
    rms = math.sqrt(rss / n)

    def coef(i: int, name: str, unit: str, note: str) -> Coefficient:
        v = float(sol.x[i])
        hw = max(Z95 * math.sqrt(max(float(cov[i, i]), 0.0)),
                 t_crit * math.sqrt(max(float(clustered[i, i]), 0.0)))
        return Coefficient(name, v, v - hw, v + hw, unit, n, math.nan, rms, "N", note)

    name = "two-state" if two_state else "one-state"
    model = DynamicsModel(
        name=name,
        tau_n_s=coef(0, "tau_n", "s", "time constant of propeller speed"),
        delay_s=coef(1, "delay", "s", "command-to-thrust dead time (sensor-to-command delay)"),
        tau_a_s=coef(2, "tau_a", "s", "time constant of the axial inflow") if two_state else None,
        gain=coef(3, "g", "1", "inflow gain: thrust overshoot per unit of s|s| - m|m|")
        if two_state else None,
        rms_n=rms, n_samples=n, lag1_corr=r1, n_params=p)
    levels = {float(c): float(sol.x[-(n_lv + 1) + i]) for i, c in enumerate(commands)}
    levels[float(series.neutral)] = 0.0
    return model, levels, float(sol.x[-1])


def _step_metrics(series: StepSeries, level: np.ndarray, tails: np.ndarray, zero: float,
                  scale: float) -> list[StepMetrics]:
    out = []
    for k in range(1, series.switch_s.size):
        a, b = float(tails[k - 1]), float(tails[k])
        if not (math.isfinite(a) and math.isfinite(b)) or abs(b - a) < MIN_STEP_FRAC * scale:
            continue
        pick = level == k
        t = series.t_s[pick] - series.switch_s[k]
        y = (series.thrust_n[pick] - zero - a) / (b - a)
        t10 = _first(t, y >= 0.1)
        t90 = _first(t, y >= 0.9)
        outside = np.flatnonzero(np.abs(y - 1) > BAND)
        settle = float(t[outside[-1] + 1]) if outside.size and outside[-1] + 1 < t.size else (
            math.nan if outside.size else 0.0)
        out.append(StepMetrics(
            float(series.command[k - 1]), float(series.command[k]), a, b,
            "up" if abs(b) > abs(a) else "down", t10, t90 - t10, settle,
            max(float(np.max(y)) - 1.0, 0.0)))
    return out


def _first(t: np.ndarray, mask: np.ndarray) -> float:
    hit = np.flatnonzero(mask)
    return float(t[hit[0]]) if hit.size else math.nan
