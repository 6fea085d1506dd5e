"""Thruster dynamics from step responses: three candidate models, chosen by held-out steps.

Speed is a state x in forward thrust units (x|x| is the forward thrust; thrust = rho x|x|
below zero, rho = C_p_rev / C_p_fwd, fitted when a step passes through zero). The candidates
(rigtool/analysis/dynamics_response.py): one-state (linear lag, tau_n), two-state ([Healey1995]
axial inflow: tau_n, tau_a, gain g), yoerger ([Yoerger1990]: x' = alpha (X|X| - x|x|)), the
Healey models when none of those fits, and rise-fall (the lag with tau_rise while |x| grows,
tau_fall while it shrinks).
The command acts `delay` seconds after it is sent. Each is fitted by least squares over every
sample (rigtool/analysis/dynamics_fit.py) with each command's steady thrust and the sensor
zero as nuisance parameters.

Selection is by prediction: the steps are split in two interleaved halves; each half's
transients (the first 70 % of every hold) are left out of a fit and then predicted by it (their
holds' last 30 % stay in, so the steady level of every command is known, as a steady sweep
would give it). The candidate with the lowest held-out error is selected; the two-state model
must also beat the one-state model by BIC, with an inflow gain of at least MIN_GAIN that is
positive with 95 % confidence. The selected model's held-out RMS, less the sensor noise, is its
adequacy: above MAX_MODEL_ERROR of full scale no candidate describes the thruster.

No dynamics are identified (`identified` False, and no export carries time constants) when the
adequacy fails, when the time constant's 95 % interval includes zero, or when the model fits no
better than a constant thrust (BIC). A run that cannot be fitted at all (fewer than two levels,
no step, time running backwards) gives None from `identify` and its reason from
`no_dynamics_reason`.

Consumers that take only a simpler model (a first-order lag, with or without separate rise and
fall constants; Yoerger's law: uuv_simulator, Stonefish) get the one-state time constant, the
rise-fall and the Yoerger fits whatever is selected; `consumer_models` gives each as it is
exported, and each one's RMS deviation from the selected model over the run
(`Dynamics.consumer_error_n`) is its adequacy: within CONSUMER_LIMIT of full scale.

Intervals: the heteroscedasticity-consistent sandwich (thrust noise grows with thrust), inflated
for serially correlated residuals (AR(1)).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from rigtool.analysis import dynamics_fit as lsq
from rigtool.analysis.dynamics_response import (
    HEALEY,
    KINDS,
    QUADRATIC_SPEED,
    ModelParams,
    thrust_response,
)
from rigtool.analysis.fits import Coefficient
from rigtool.analysis.stats import (
    MAX_R1_FIT,
    ar1_coefficient,
    effective_sample_size,
    lag1_autocorrelation,
)
from rigtool.progress_hook import ProgressHook, no_progress

Z95 = 1.959963984540054
BIC_MARGIN = 10.0
MIN_GAIN = 0.01
MIN_RISE_FALL = 0.05  # rise and fall constants closer than this fraction: one time constant
CONSUMER_LIMIT = 0.02  # a consumer's simpler model within this fraction of full scale: adequate
CONSUMERS = ("first-order", "rise-fall", "yoerger")
TAIL_FRAC = 0.3  # last part of each hold taken as its steady level (starting values, metrics)
MIN_STEP_FRAC = 0.05  # steps smaller than this fraction of full scale get no timing metrics
BAND = 0.05  # settling band, fraction of the step
SETTLED_FOR_FRAC = 0.1  # in the band for this fraction of the hold (and 5 samples) to count
MAX_MODEL_ERROR = 0.05  # held-out model error above this fraction of full scale: inadequate
MIN_SAMPLES = 20
MAX_FIT_SAMPLES = 60_000  # longer runs are fitted on every k-th sample
HELD_OUT_ITER = 8  # iterations of a held-out fit (started from the fit to every sample)
MAX_PARAM_SHIFT = 0.05  # small-step and large-step fits may not differ by this fraction ...
Z_SHIFT = 3.29  # ... and by this many standard errors (99.9 %)
SHIFT_ITER = 30  # iterations of those fits (started from the fit to every sample)
HEALEY_TRIGGER = 0.005  # Healey's inflow is tried when no closed-form model fits this well
NOTES = {"tau_n": ("s", "time constant of propeller speed"),
         "tau_fall": ("s", "time constant of propeller speed while |speed| shrinks (spin-down)"),
         "delay": ("s", "command-to-thrust dead time (sensor-to-command delay)"),
         "tau_a": ("s", "time constant of the axial inflow"),
         "g": ("1", "inflow gain: thrust overshoot per unit of x|x| - m|m|"),
         "alpha": ("1/(sqrt(N) s)", "Yoerger damping: x' = alpha (X|X| - x|x|)"),
         "rho": ("1", "C_p_rev / C_p_fwd seen in the transients"),
         "beta": ("1/(sqrt(N) s)", "Healey inflow: m' = beta (x|x| - m|m|)")}
ANTICAUSAL_TAU_FRAC = 0.25  # thrust leading its command by more (x tau_n, or 2 samples): no dynamics


@dataclass(frozen=True)
class StepSeries:
    """The samples of a step-response run in time order, and when each level was commanded."""

    t_s: np.ndarray
    thrust_n: np.ndarray
    switch_s: np.ndarray  # command time of each level (run clock)
    command: np.ndarray  # command of each level
    neutral: float

    def level_of_sample(self) -> np.ndarray:
        """Index of the level in force at each sample (0 before the first switch)."""
        return np.clip(np.searchsorted(self.switch_s, self.t_s, side="right") - 1, 0, None)


@dataclass
class DynamicsModel:
    """One fitted model: its parameters with 95 % intervals and its fit quality."""

    name: str  # "one-state" | "two-state" | "yoerger"
    tau_n_s: Coefficient  # yoerger: the local time constant 1 / (2 alpha sqrt(F)) at the
    delay_s: Coefficient  # largest level F (derived)
    tau_a_s: Coefficient | None
    gain: Coefficient | None
    rms_n: float
    n_samples: int
    lag1_corr: float = 0.0  # lag-1 autocorrelation of the residuals
    n_params: int = 0  # (defaults: stored by an older rigtool, which kept only bic and aic)
    bic: float = math.nan  # set by identify, on an effective sample size common to all models
    aic: float = math.nan
    alpha: Coefficient | None = None  # yoerger
    reverse_ratio: Coefficient | None = None  # rho; None: no step through zero (rho = 1)
    heldout_rms_n: float = math.nan  # RMS error predicting the held-out transients
    heldout_noise_n: float = math.nan  # sensor noise RMS on those samples
    levels: dict[float, float] | None = None  # this model's own level fit (command -> N)
    zero_n: float = math.nan
    inflow_beta: Coefficient | None = None  # healey, healey-lag
    tau_fall_s: Coefficient | None = None  # rise-fall (its tau_n_s is the rise constant)
    fall_minus_rise: Coefficient | None = None  # rise-fall: tau_fall - tau_rise

    def model_params(self) -> ModelParams:
        """The parameters `thrust_response` takes."""
        kind = self.name if self.name in KINDS else (
            "two-state" if self.gain is not None else "one-state")
        return ModelParams(
            kind, tau_n=self.tau_n_s.value, delay=self.delay_s.value,
            alpha=self.alpha.value if self.alpha else 1.0,
            tau_a=self.tau_a_s.value if self.tau_a_s else 1.0,
            gain=self.gain.value if self.gain else 0.0,
            rho=self.reverse_ratio.value if self.reverse_ratio else 1.0,
            beta=self.inflow_beta.value if self.inflow_beta else 1.0,
            tau_fall=self.tau_fall_s.value if self.tau_fall_s else 1.0)

    def rise_fall_differ(self) -> bool:
        """Whether the rise and fall constants differ with 95 % confidence."""
        d = self.fall_minus_rise
        return d is not None and (d.lo > 0 or d.hi < 0)

    def params(self) -> tuple[float, float, float, float]:
        """(tau_n, tau_a, g, delay) of the linear models."""
        p = self.model_params()
        return float(p.tau_n), float(p.tau_a), float(p.gain), float(p.delay)

    def model_error_n(self) -> float:
        """Held-out RMS error with the sensor noise taken out (N)."""
        return math.sqrt(max(self.heldout_rms_n**2 - self.heldout_noise_n**2, 0.0))


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
    settling_s: float  # NaN when not settled in the window (see `settled`)
    overshoot_frac: float
    settled: bool = True  # False: still outside the band, or only just inside, at the end
    window_s: float = math.nan  # length of the hold the step was measured over


@dataclass
class Dynamics:
    """The candidate models, the one the data support, and the measured step timings."""

    one_state: DynamicsModel
    two_state: DynamicsModel | None
    selected: str
    steps: list[StepMetrics]
    levels: dict[float, float]  # command -> fitted steady thrust (N)
    zero_n: float
    warnings: list[str] = field(default_factory=list)
    yoerger: DynamicsModel | None = None
    identified: bool = True  # False: no time constants to carry into any export
    reason: str = ""  # why not identified
    full_scale_n: float = math.nan  # the adequacy's reference
    healey_lag: DynamicsModel | None = None
    healey: DynamicsModel | None = None
    rise_fall: DynamicsModel | None = None
    consumer_error_n: dict[str, float] = field(default_factory=dict)  # see consumer_models

    @property
    def model(self) -> DynamicsModel:
        """The selected model."""
        return dict(self.slots()).get(self.selected) or self.one_state

    def slots(self) -> list[tuple[str, DynamicsModel | None]]:
        """(candidate name, its model or None) for every candidate."""
        return list(zip(KINDS, (self.one_state, self.two_state, self.yoerger, self.healey_lag,
                                self.healey, self.rise_fall), strict=True))

    @property
    def candidates(self) -> list[DynamicsModel]:
        """Every fitted model, in candidate order."""
        return [m for _, m in self.slots() if m is not None]

    def fitted(self, series: StepSeries, model: DynamicsModel | None = None) -> np.ndarray:
        """A model's fitted thrust (N, with the sensor zero) on the series' samples."""
        m = model or self.model
        levels = m.levels if m.levels is not None else self.levels
        zero = m.zero_n if math.isfinite(m.zero_n) else self.zero_n
        f = np.array([levels.get(float(c), 0.0) for c in series.command])
        return thrust_response(series.t_s, series.switch_s, f, m.model_params()) + zero


def response(t_s: np.ndarray, switch_s: np.ndarray, target: np.ndarray, tau_n: float,
             tau_a: float, gain: float, delay: float) -> np.ndarray:
    """Linear-model thrust (N, without sensor zero) after levels with speed targets `target`
    (signed square roots of the steady thrusts, rho = 1) commanded at `switch_s`."""
    tgt = np.asarray(target, dtype=float)
    p = ModelParams("two-state", tau_n=tau_n, tau_a=tau_a, gain=gain, delay=delay)
    return thrust_response(t_s, switch_s, tgt * np.abs(tgt), p)


def speed_target(thrust_n: np.ndarray | float) -> np.ndarray:
    """Signed square root: the speed state (thrust units, rho = 1) that holds `thrust_n`."""
    f = np.asarray(thrust_n, dtype=float)
    return np.sign(f) * np.sqrt(np.abs(f))


def simulate(model: DynamicsModel, t_s: np.ndarray, command: np.ndarray,
             steady_thrust: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """Thrust (N) the model predicts for a command time series: `command[i]` holds from
    `t_s[i]`; `steady_thrust` maps a command to its steady thrust (e.g. `cal.thrust`)."""
    t = np.asarray(t_s, dtype=float)
    c = np.asarray(command, dtype=float)
    change = np.concatenate(([True], c[1:] != c[:-1]))
    levels = np.nan_to_num(np.asarray(steady_thrust(c[change]), dtype=float))
    return thrust_response(t, t[change], levels, model.model_params())


def simulate_document(doc: dict, t_s: np.ndarray, command: np.ndarray,
                      steady_thrust: Callable[[np.ndarray], np.ndarray] | None = None
                      ) -> np.ndarray:
    """`simulate` for calibration.json's `dynamics` (the selected model); by default the step
    run's own levels, interpolated in speed."""
    m = doc["models"][doc["selected"]]

    def value(key: str, default: float) -> float:
        c = m.get(key)
        return float(c["value"]) if isinstance(c, dict) else default

    kind = doc["selected"] if doc["selected"] in KINDS else "two-state"
    p = ModelParams(kind, tau_n=value("tau_n", 1.0), alpha=value("alpha", 1.0),
                    tau_a=value("tau_a", 1.0), gain=value("g", 0.0), delay=value("delay", 0.0),
                    rho=value("rho", 1.0), beta=value("beta", 1.0),
                    tau_fall=value("tau_fall", 1.0))
    if steady_thrust is None:
        steady_thrust = _level_map(doc["levels"], float(p.rho))
    t = np.asarray(t_s, dtype=float)
    c = np.asarray(command, dtype=float)
    change = np.concatenate(([True], c[1:] != c[:-1]))
    levels = np.nan_to_num(np.asarray(steady_thrust(c[change]), dtype=float))
    return thrust_response(t, t[change], levels, p)


def _level_map(levels: list[dict], rho: float) -> Callable[[np.ndarray], np.ndarray]:
    """Steady thrust of any command from the step run's levels, interpolated in speed."""
    known = sorted((float(x["command"]), float(x["thrust_n"] or 0.0)) for x in levels)
    cmd = np.array([k for k, _ in known])
    f = np.array([v for _, v in known])
    speed = np.sign(f) * np.sqrt(np.abs(f) / np.where(f >= 0, 1.0, rho))

    def steady(c: np.ndarray) -> np.ndarray:
        s = np.interp(c, cmd, speed)
        return np.where(s >= 0, 1.0, rho) * s * np.abs(s)

    return steady


# ----- preparing a run ------------------------------------------------------------------------


def no_dynamics_reason(series: StepSeries) -> str | None:
    """Why a run cannot be fitted at all (one line), or None when it can."""
    prepared = _prepare(series)
    return prepared if isinstance(prepared, str) else None


def _prepare(series: StepSeries) -> tuple[StepSeries, list[str]] | str:
    """The fittable part of a run and notes on what was left out, or the reason it has none."""
    t = np.asarray(series.t_s, dtype=float).ravel()
    f = np.asarray(series.thrust_n, dtype=float).ravel()
    sw = np.asarray(series.switch_s, dtype=float).ravel()
    cmd = np.asarray(series.command, dtype=float).ravel()
    if t.size != f.size or sw.size != cmd.size:
        return "the samples' times and thrusts (or the levels' times and commands) differ in number"
    if not (np.isfinite(sw).all() and np.isfinite(cmd).all()):
        return "a level has no finite command or command time"
    if sw.size > 1 and np.any(np.diff(sw) < 0):
        return "the command times go backwards: no time axis to fit a response on"
    ok = np.isfinite(t) & np.isfinite(f)
    notes = [] if ok.all() else [f"dynamics: {int(np.sum(~ok))} sample(s) with a missing or "
                                 "non-finite time or thrust are left out"]
    t, f = t[ok], f[ok]
    backwards = int(np.sum(np.diff(t) < 0)) if t.size > 1 else 0
    reason = _shape_reason(t, sw, cmd, backwards)
    if reason:
        return reason
    if t.size > MAX_FIT_SAMPLES:
        stride = math.ceil(t.size / MAX_FIT_SAMPLES)
        t, f = t[::stride], f[::stride]
        notes.append(f"dynamics: fitted on every {stride}th sample ({t.size} of them)")
    return StepSeries(t, f, sw, cmd, float(series.neutral)), notes


def _shape_reason(t: np.ndarray, sw: np.ndarray, cmd: np.ndarray, backwards: int) -> str | None:
    """The reason a run's time axis or levels give nothing to fit, if any."""
    if backwards:
        return f"the sample times go backwards ({backwards} time(s)): no time axis"
    if t.size < MIN_SAMPLES:
        return f"{t.size} usable sample(s); at least {MIN_SAMPLES} are needed"
    if not t[-1] > t[0]:
        return "every sample has the same time stamp: no time axis"
    if sw.size < 2:
        return "fewer than two levels: no step"
    if np.unique(cmd).size < 2:
        return f"every level commands {cmd[0]:g}: no step"
    return None


# ----- identification -------------------------------------------------------------------------


@dataclass(frozen=True)
class _Run:
    """A prepared run with the starting values every candidate shares."""

    series: StepSeries
    level: np.ndarray  # level index of each sample
    tails: np.ndarray  # tail mean of each hold (NaN: no samples)
    commands: np.ndarray  # commands with a thrust parameter (not neutral)
    level_idx: np.ndarray  # per level: index into `commands`, -1 for neutral
    start_levels: np.ndarray
    zero: float
    scale: float  # full scale (N)
    tau0: float
    crosses: bool  # a step passes through zero
    both_signs: bool  # levels of both thrust directions
    transient: np.ndarray  # sample in the first 1 - TAIL_FRAC of its hold
    fold: np.ndarray  # held-out fold of each sample (0 or 1)
    direction_fold: np.ndarray  # the same, alternating within steps up, down, through zero


def identify(series: StepSeries, full_scale_n: float | None = None,
             progress: ProgressHook = no_progress) -> Dynamics | None:
    """Fit the candidate models (each reported to `progress`), select by held-out steps and
    judge adequacy; None when the run cannot be fitted at all (`no_dynamics_reason` says
    why)."""
    prepared = _prepare(series)
    if isinstance(prepared, str):
        return None
    clean, notes = prepared
    run = _setup(clean, full_scale_n)
    if run is None:
        return None
    fits = _candidates(run, progress)
    if "one-state" not in fits:
        return None
    models = {kind: f[0] for kind, f in fits.items()}
    _set_criteria(models, run)
    selected = _select(models)
    best = models[selected]
    steps = _step_metrics(clean, run.level, run.tails - run.zero, run.zero, run.scale,
                          dict(zip(run.commands.tolist(), run.start_levels.tolist(), strict=True)))
    dyn = Dynamics(models["one-state"], models.get("two-state"), selected, steps,
                   dict(best.levels or {}), best.zero_n, list(notes), models.get("yoerger"),
                   full_scale_n=run.scale, healey_lag=models.get("healey-lag"),
                   healey=models.get("healey"), rise_fall=models.get("rise-fall"))
    dyn.consumer_error_n = _consumer_errors(dyn, clean)
    return _judge(dyn, run, *fits[selected][1:])


# ----- what consumers with a simpler model get ------------------------------------------------


def selected_tau(dyn: Dynamics) -> Coefficient:
    """The selected model's speed time constant (time_constant_s): its tau_n (a Yoerger
    model's local one at the largest level), the one-state fit's when rise-fall is selected."""
    return (dyn.one_state if dyn.selected == "rise-fall" else dyn.model).tau_n_s


def first_order_tau(dyn: Dynamics) -> Coefficient:
    """The single time constant a first-order consumer gets: the one-state fit's, the best
    single lag for the thrust whatever is selected (the selected model's tau_n leaves out its
    inflow or quadratic law)."""
    return dyn.one_state.tau_n_s


def exported_yoerger(dyn: Dynamics) -> DynamicsModel | None:
    """The model whose alpha is exported as Yoerger's: the selected one when its speed follows
    Yoerger's law (yoerger, healey), else the yoerger candidate (None: not fitted)."""
    return dyn.model if dyn.selected in QUADRATIC_SPEED else dyn.yoerger


def consumer_models(dyn: Dynamics) -> dict[str, ModelParams | None]:
    """Each simpler model as it is exported (None: not fitted), with the selected model's
    command delay: first-order (the single time constant), rise-fall, yoerger."""
    m = dyn.model
    delay = m.delay_s.value
    rho = m.reverse_ratio.value if m.reverse_ratio else 1.0
    rf, yo = dyn.rise_fall, exported_yoerger(dyn)
    return {
        "first-order": ModelParams("one-state", tau_n=first_order_tau(dyn).value, delay=delay,
                                   rho=rho),
        "rise-fall": None if rf is None or rf.tau_fall_s is None else ModelParams(
            "rise-fall", tau_n=rf.tau_n_s.value, tau_fall=rf.tau_fall_s.value, delay=delay,
            rho=rho),
        "yoerger": None if yo is None or yo.alpha is None else ModelParams(
            "yoerger", alpha=yo.alpha.value, delay=delay,
            rho=yo.reverse_ratio.value if yo.reverse_ratio else 1.0)}


def _consumer_errors(dyn: Dynamics, series: StepSeries) -> dict[str, float]:
    """RMS difference (N) over the run between each simpler model and the selected one, both
    driven by the selected model's levels (NaN: not fitted)."""
    levels = dyn.model.levels if dyn.model.levels is not None else dyn.levels
    f = np.array([levels.get(float(c), 0.0) for c in series.command])
    selected = thrust_response(series.t_s, series.switch_s, f, dyn.model.model_params())
    out = {}
    for name, p in consumer_models(dyn).items():
        if p is None:
            out[name] = math.nan
            continue
        d = thrust_response(series.t_s, series.switch_s, f, p) - selected
        out[name] = math.sqrt(float(np.mean(d**2))) if d.size else math.nan
    return out


def consumer_adequate(dyn: Dynamics, name: str) -> bool:
    """Whether a simpler model stands for the selected one within CONSUMER_LIMIT of full
    scale (only when dynamics were identified)."""
    err = dyn.consumer_error_n.get(name, math.nan)
    return bool(dyn.identified and dyn.full_scale_n > 0
                and err <= CONSUMER_LIMIT * dyn.full_scale_n)


def _setup(series: StepSeries, full_scale_n: float | None) -> _Run | None:
    """Levels, starting values and held-out folds of a prepared run; None without a step."""
    level = series.level_of_sample()
    tails = _tail_means(series, level)
    neutral = np.isclose(series.command, series.neutral)
    zero = float(np.nanmean(tails[neutral])) if np.isfinite(tails[neutral]).any() else 0.0
    commands = np.unique(series.command[~neutral])
    level_idx = np.where(neutral, -1, np.searchsorted(commands, series.command))
    start = np.array([np.nanmean(tails[series.command == c]) - zero
                      if np.isfinite(tails[series.command == c]).any() else 0.0
                      for c in commands])
    rel = tails - zero
    measured = float(np.nanmax(np.abs(rel))) if np.isfinite(rel).any() else 0.0
    scale = full_scale_n or measured
    if not scale > 0 or not commands.size:
        return None
    thrust = np.where(level_idx >= 0, start[np.clip(level_idx, 0, None)], 0.0)
    transient, fold = _folds(series, level)
    return _Run(series, level, tails, commands, level_idx, start, zero, scale,
                _first_time_constant(series, level, tails), _crosses_zero(thrust, scale),
                _both_signs(start, scale), transient, fold,
                _direction_folds(thrust, scale)[level])


def _crosses_zero(thrust: np.ndarray, scale: float) -> bool:
    """True when consecutive levels hold clearly opposite thrusts (a step through zero)."""
    big = np.abs(thrust) > MIN_STEP_FRAC * scale
    return bool(np.any(big[1:] & big[:-1] & (np.sign(thrust[1:]) != np.sign(thrust[:-1]))))


def _both_signs(start: np.ndarray, scale: float) -> bool:
    """True when the run holds clearly forward and clearly reverse levels."""
    big = np.abs(start) > MIN_STEP_FRAC * scale
    return bool(np.any(big & (start > 0)) and np.any(big & (start < 0)))


def _direction_folds(thrust: np.ndarray, scale: float) -> np.ndarray:
    """Per level, a fold that alternates within each kind of step (|thrust| up, down, through
    zero): alternate levels of a run that steps out and back are all up or all down, and
    rise-fall fitted on one kind alone cannot predict the other."""
    before = np.concatenate(([0.0], thrust[:-1]))
    big = MIN_STEP_FRAC * scale
    through = (np.abs(thrust) > big) & (np.abs(before) > big) & (np.sign(thrust)
                                                                 != np.sign(before))
    kind = np.where(through, 2, np.where(np.abs(thrust) > np.abs(before), 0, 1))
    fold = np.zeros(thrust.size, dtype=int)
    for k in range(3):
        pick = np.flatnonzero(kind == k)
        fold[pick] = np.arange(pick.size) % 2
    return fold


def _folds(series: StepSeries, level: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Whether each sample lies in its hold's transient part, and its hold's fold."""
    ends = np.append(series.switch_s[1:], max(float(series.t_s[-1]), float(series.switch_s[-1])))
    start = series.switch_s[level]
    hold = np.maximum(ends[level] - start, 0.0)
    transient = series.t_s - start < (1 - TAIL_FRAC) * hold
    return transient, level % 2


Fitted = tuple["DynamicsModel", lsq.Problem, lsq.FitResult]
PRIORS = {"one-state": (), "two-state": ("one-state",), "yoerger": ("one-state",),
          "rise-fall": ("one-state",),
          "healey-lag": ("one-state", "two-state"),
          "healey": ("one-state", "two-state", "yoerger")}


def _candidates(run: _Run, progress: ProgressHook = no_progress) -> dict[str, Fitted]:
    """The closed-form candidates; Healey's inflow too when none of them fits within
    HEALEY_TRIGGER of full scale (it has no closed form, so it costs more). Each candidate
    tried is reported to `progress` (of the six there can be)."""
    fits: dict[str, Fitted] = {}
    task, total, tried = "dynamics candidates", len(PRIORS), 0
    progress(task, 0, total)
    for kind in (*KINDS[:3], "rise-fall"):
        if kind != "one-state" and "one-state" not in fits:
            break
        fit = _candidate(run, kind, [fits[k][1:] for k in PRIORS[kind] if k in fits])
        tried += 1
        progress(task, tried, total)
        if fit is not None:
            fits[kind] = fit
    for kind in _healey_order(fits):
        if not _misfit(fits, run):
            break
        fit = _candidate(run, kind, [fits[k][1:] for k in PRIORS[kind] if k in fits])
        tried += 1
        progress(task, tried, total)
        if fit is not None:
            fits[kind] = fit
    progress(task, total, total)
    return fits


def _healey_order(fits: dict[str, Fitted]) -> list[str]:
    """The Healey candidates, the one whose speed law fits better first (the second is only
    tried if the first misses too)."""
    def error(kind: str) -> float:
        return fits[kind][0].model_error_n() if kind in fits else math.inf

    quadratic_first = error("yoerger") < min(error("one-state"), error("two-state"))
    return ["healey", "healey-lag"] if quadratic_first else ["healey-lag", "healey"]


def _misfit(fits: dict[str, Fitted], run: _Run) -> bool:
    """True when the best closed-form candidate misses by more than HEALEY_TRIGGER."""
    errors = [f[0].model_error_n() for f in fits.values()]
    return bool(errors) and min(errors) > HEALEY_TRIGGER * run.scale


def _candidate(run: _Run, kind: str, prior: list[tuple[lsq.Problem, lsq.FitResult]]
               ) -> Fitted | None:
    """One model fitted to every sample (started from the `prior` fits), then validated on
    the held-out transients."""
    problem = _problem(run, kind)
    try:
        x0 = _start(run, problem, prior)
        if kind in HEALEY:
            problem = replace(problem, grid_s=_grid(run, problem, x0))
        res = lsq.fit(problem, x0)
    except (ValueError, FloatingPointError, np.linalg.LinAlgError):
        return None
    if not np.isfinite(res.natural).all() or not np.isfinite(res.residual).all():
        return None
    model = _model(run, problem, res)
    fold = run.direction_fold if kind == "rise-fall" else run.fold
    model.heldout_rms_n, model.heldout_noise_n = _held_out(run, problem, res, fold)
    return model, problem, res


def _problem(run: _Run, kind: str) -> lsq.Problem:
    """The least-squares problem of one candidate; rho is free where it matters: through
    zero for the linear models, between directions for the nonlinear ones."""
    s = run.series
    fit_rho = run.both_signs if kind in QUADRATIC_SPEED | HEALEY else run.crosses
    return lsq.Problem(kind, s.t_s, s.thrust_n, s.switch_s, run.level_idx, run.commands.size,
                       fit_rho)


def _x_big(run: _Run) -> float:
    """Speed (sqrt(N)) of the largest level."""
    return math.sqrt(float(np.max(np.abs(run.start_levels))) or 1.0)


def _grid(run: _Run, problem: lsq.Problem, x0: np.ndarray) -> float:
    """Healey node spacing base: the starting speed time constant (at the largest level)."""
    value = dict(zip(problem.names, x0[:len(problem.names)], strict=True))
    if "alpha" in value:
        return 1.0 / (2.0 * float(value["alpha"]) * _x_big(run))
    return float(value["tau_n"])


def _start(run: _Run, problem: lsq.Problem, prior: list[tuple[lsq.Problem, lsq.FitResult]]
           ) -> np.ndarray:
    """Starting vector: the values of the `prior` fits (the 63 % time of the largest step and
    the levels' tail means without any), the best of a few values for the parameters they
    lack."""
    dt = float(np.median(np.diff(run.series.t_s))) if run.series.t_s.size > 1 else 0.0
    x_big = _x_big(run)
    value = {"tau_n": run.tau0, "delay": dt, "rho": 1.0}
    levels, zero = list(run.start_levels), run.zero
    for prob, res in prior:
        d = len(prob.names)
        value |= {n: float(v) for n, v in zip(prob.names, res.natural[:d], strict=True)}
        levels, zero = list(res.natural[d:-1]), float(res.natural[-1])
    tau = value["tau_n"]
    options = {"alpha": [0.745 / (tau * x_big) * k for k in (1.0, 0.5, 2.0)],
               "tau_fall": [tau * k for k in (1.0, 0.5, 2.0)],
               "tau_a": [tau * k for k in (1.5, 3.0, 6.0)], "g": [0.1, 0.3],
               "beta": [1 / (2 * tau * k * x_big) for k in (1.5, 3.0, 6.0)]}
    if value.get("g", 0.0) > 0 and "tau_a" in value:  # an inflow the two-state fit found
        options["g"].append(value["g"])
        options["beta"].append(1 / (2 * value["tau_a"] * x_big))
    grid = [value]
    for name in problem.names:
        if name not in value or (problem.kind in HEALEY and name in ("g", "beta")):
            grid = [v | {name: o} for v in grid for o in options[name]]
    starts = [np.array([v[n] for n in problem.names] + levels + [zero]) for v in grid]
    if len(starts) == 1:
        return starts[0]
    costs = [float(np.sum((problem.y - lsq.predict(problem, x)) ** 2)) for x in starts]
    return starts[int(np.nanargmin(costs))]


def _model(run: _Run, problem: lsq.Problem, res: lsq.FitResult) -> DynamicsModel:
    """Coefficients with intervals from a fit."""
    r = res.residual[res.mask]
    n = r.size
    cov, r1 = _covariance(res.jac, r, run.level[res.mask])
    rms = math.sqrt(float(r @ r) / n)
    names = problem.names
    coefs = {name: _coef(name, float(res.natural[j]), cov[j, j], n, rms)
             for j, name in enumerate(names)}
    d = len(names)
    levels = {float(c): float(res.natural[d + i]) for i, c in enumerate(run.commands)}
    levels[float(run.series.neutral)] = 0.0
    x_big = _x_big(run)
    tau = coefs.get("tau_n") or _local_tau(coefs["alpha"], "tau_n", x_big, n, rms)
    fall = coefs.get("tau_fall")
    difference = None
    if fall is not None:
        tau = replace(tau, name="tau_rise", note="time constant of propeller speed while "
                      "|speed| grows (spin-up)")
        jr, jf = names.index("tau_n"), names.index("tau_fall")
        var = cov[jr, jr] + cov[jf, jf] - 2 * cov[jr, jf]
        difference = replace(_coef("tau_fall", fall.value - tau.value, var, n, rms),
                             name="tau_fall - tau_rise", note="fall minus rise time constant")
    tau_a = coefs.get("tau_a") or (_local_tau(coefs["beta"], "tau_a", x_big, n, rms)
                                   if "beta" in coefs else None)
    return DynamicsModel(
        name=problem.kind, tau_n_s=tau, delay_s=coefs["delay"], tau_a_s=tau_a,
        gain=coefs.get("g"), rms_n=rms, n_samples=n, lag1_corr=r1, n_params=problem.n_params,
        alpha=coefs.get("alpha"), reverse_ratio=coefs.get("rho"), levels=levels,
        zero_n=float(res.natural[-1]), inflow_beta=coefs.get("beta"), tau_fall_s=fall,
        fall_minus_rise=difference)


def _coef(name: str, value: float, var: float, n: int, rms: float) -> Coefficient:
    unit, note = NOTES[name]
    hw = Z95 * math.sqrt(max(var, 0.0)) if math.isfinite(var) else math.inf
    return Coefficient(name, value, value - hw, value + hw, unit, n, math.nan, rms, "N", note)


def _local_tau(rate: Coefficient, name: str, x_big: float, n: int, rms: float) -> Coefficient:
    """A quadratic law's local time constant at the largest level, 1 / (2 rate sqrt(F))."""
    value = 1.0 / (2 * rate.value * x_big)
    rel = (rate.hi - rate.value) / rate.value if rate.value > 0 else math.inf
    return Coefficient(name, value, value * (1 - rel), value * (1 + rel), "s", n, math.nan,
                       rms, "N", f"local time constant at the largest level "
                       f"({x_big * x_big:.4g} N), from {rate.name}")


def _covariance(jac: np.ndarray, r: np.ndarray, hold: np.ndarray) -> tuple[np.ndarray, float]:
    """Heteroscedasticity-consistent covariance inflated for AR(1) residuals (neighbours at one
    held command only); lag-1 corr."""
    r1 = ar1_coefficient(lag1_autocorrelation(r, hold[1:] == hold[:-1], float(r @ r)),
                         MAX_R1_FIT)
    bread = np.linalg.pinv(jac.T @ jac)
    jr = jac * r[:, None]
    return bread @ (jr.T @ jr) @ bread * (1 + r1) / (1 - r1), r1


def _held_out(run: _Run, problem: lsq.Problem, res: lsq.FitResult,
              fold: np.ndarray) -> tuple[float, float]:
    """(RMS error, noise RMS) on the transients of each fold, predicted by a fit without them
    (every transient sample is predicted once, whichever the folds)."""
    errors, noise = [], []
    diffs = _noise_terms(res.residual, run.level)
    for f in (0, 1):
        out = run.transient & (fold == f)
        if not out.any() or out.all():
            continue
        try:
            held = lsq.fit(problem, res.natural, ~out, with_jacobian=False,
                           max_iter=HELD_OUT_ITER)
        except (ValueError, FloatingPointError, np.linalg.LinAlgError):
            return math.inf, math.nan
        errors.append(held.residual[out])
        noise.append(diffs[out])
    if not errors:
        return math.nan, math.nan
    e = np.concatenate(errors)
    d = np.concatenate(noise)
    d = d[np.isfinite(d)]
    rms = math.sqrt(float(np.mean(e**2))) if np.isfinite(e).all() else math.inf
    return rms, math.sqrt(float(np.mean(d))) if d.size else math.nan


def _noise_terms(residual: np.ndarray, level: np.ndarray) -> np.ndarray:
    """Per sample, half the squared difference of residuals with the next sample of its hold
    (its mean is the white-noise variance); NaN at a hold's end."""
    out = np.full(residual.size, np.nan)
    same = level[1:] == level[:-1]
    out[:-1] = np.where(same, 0.5 * np.diff(residual) ** 2, np.nan)
    return out


def _set_criteria(models: dict[str, DynamicsModel], run: _Run) -> None:
    """BIC and AIC of every model on one effective sample size (from the richest model)."""
    richest = max(models.values(), key=lambda m: m.n_params)
    r1 = richest.lag1_corr
    n_eff = effective_sample_size(richest.n_samples, r1, richest.n_params + 1.0)
    for m in models.values():
        fit = n_eff * math.log(max(m.rms_n, 1e-150) ** 2)
        m.bic = fit + m.n_params * math.log(n_eff)
        m.aic = fit + 2 * m.n_params


INFLOW_BASE = {"two-state": "one-state", "healey-lag": "one-state", "healey": "yoerger"}


def _select(models: dict[str, DynamicsModel]) -> str:
    """The candidate with the lowest held-out error that the data support: an inflow model
    must beat its speed law alone by BIC, with a gain of at least MIN_GAIN that is positive
    with 95 % confidence; rise-fall must beat one-state by BIC, with rise and fall constants
    that differ with 95 % confidence and by at least MIN_RISE_FALL."""
    allowed = dict(models)
    for kind, base in (*INFLOW_BASE.items(), ("rise-fall", "one-state")):
        m, b = models.get(kind), models.get(base)
        if m is not None and not (b is not None and m.bic < b.bic - BIC_MARGIN
                                  and _richer_supported(m)):
            allowed.pop(kind)

    def error(m: DynamicsModel) -> float:
        return m.heldout_rms_n if math.isfinite(m.heldout_rms_n) else math.inf

    return min(allowed, key=lambda k: (error(allowed[k]), KINDS.index(k)))


def _richer_supported(m: DynamicsModel) -> bool:
    """The extra structure of an inflow or rise-fall model is there: a gain of at least
    MIN_GAIN, positive with 95 % confidence; rise and fall constants that differ."""
    if m.gain is not None:
        return m.gain.lo > 0 and m.gain.value >= MIN_GAIN
    d = m.fall_minus_rise
    return (m.rise_fall_differ() and d is not None
            and abs(d.value) >= MIN_RISE_FALL * min(m.tau_n_s.value, d.value + m.tau_n_s.value))


def _judge(dyn: Dynamics, run: _Run, problem: lsq.Problem, res: lsq.FitResult) -> Dynamics:
    """Mark the dynamics not identified when the selected model is not supported."""
    m = dyn.model
    reason = _not_identified(m, run) or _size_dependence(m, run, problem, res)
    if reason is None:
        return dyn
    dyn.warnings.append(f"dynamics: no dynamics identified: {reason}; no time constants are "
                        "exported")
    return replace(dyn, identified=False, reason=reason)


def _not_identified(m: DynamicsModel, run: _Run) -> str | None:
    """Why the selected model cannot stand for this thruster, if it cannot."""
    rates = [m.alpha] if m.alpha is not None else [m.tau_n_s, m.tau_fall_s]
    for rate in (r for r in rates if r is not None):
        if not rate.lo > 0:
            return (f"the {rate.name} of the {m.name} model has a 95 % interval "
                    f"{rate.lo:.3g} .. {rate.hi:.3g} {rate.unit}, which includes zero")
    dt = float(np.median(np.diff(run.series.t_s))) if run.series.t_s.size > 1 else 0.0
    if m.delay_s.hi < -max(ANTICAUSAL_TAU_FRAC * m.tau_n_s.value, 2.0 * dt):
        return (f"the thrust moves {-m.delay_s.value:.3g} s before its command (delay "
                f"{m.delay_s.lo:.3g} .. {m.delay_s.hi:.3g} s): the command and thrust times "
                "do not belong together (a clock offset in the log?)")
    if not m.bic < _constant_bic(run, m) - BIC_MARGIN:
        return f"the {m.name} model fits no better than a constant thrust (BIC)"
    err = m.model_error_n()
    if not err <= MAX_MODEL_ERROR * run.scale:
        return (f"no candidate describes this thruster: the best ({m.name}) predicts held-out "
                f"steps with an RMS error of {err:.3g} N beyond the sensor noise, "
                f"{100 * err / run.scale:.1f} % of full scale ({run.scale:.3g} N; limit "
                f"{100 * MAX_MODEL_ERROR:g} %)")
    return None


def _size_dependence(m: DynamicsModel, run: _Run, problem: lsq.Problem,
                     res: lsq.FitResult) -> str | None:
    """The model refitted on the small and on the large steps: a dynamics parameter (not rho,
    the steady map's) that differs by more than MAX_PARAM_SHIFT, beyond its intervals
    (Z_SHIFT), means the model does not describe the thruster (its dynamics depend on the
    step size)."""
    small = _small_steps(run)
    if small is None:
        return None
    parts = []
    for group in (True, False):
        out = run.transient & (small[run.level] != group)
        try:
            part = lsq.fit(problem, res.natural, ~out, max_iter=SHIFT_ITER)
        except (ValueError, FloatingPointError, np.linalg.LinAlgError):
            return None
        parts.append((part.natural, _covariance(part.jac, part.residual[part.mask],
                                                run.level[part.mask])[0]))
    (a, cov_a), (b, cov_b) = parts
    for j, name in enumerate(problem.names):
        if name == "rho":  # the steady map's, and small steps through zero hardly show it
            continue
        shift = abs(a[j] - b[j])
        se = math.sqrt(max(cov_a[j, j] + cov_b[j, j], 0.0))
        if shift > Z_SHIFT * se and shift > MAX_PARAM_SHIFT * _shift_scale(m, name, res, j):
            return (f"no candidate describes this thruster: the {m.name} model's {name} is "
                    f"{a[j]:.4g} on the small steps and {b[j]:.4g} on the large ones "
                    "(its dynamics depend on the step size)")
    return None


def _shift_scale(m: DynamicsModel, name: str, res: lsq.FitResult, j: int) -> float:
    """What a parameter's shift is compared with: its value; the time constant for the
    delay; 1 for the inflow gain (a shift of g by 0.05 moves the overshoot by about 5 % of
    the step)."""
    if name == "delay":
        return m.tau_n_s.value
    if name == "g":
        return 1.0
    return abs(float(res.natural[j]))


def _small_steps(run: _Run) -> np.ndarray | None:
    """Per level, whether its step (in speed units) is below the median step; None when
    the steps do not differ in size."""
    target = speed_target(np.where(run.level_idx >= 0,
                                   run.start_levels[np.clip(run.level_idx, 0, None)], 0.0))
    size = np.abs(np.diff(target, prepend=0.0))
    big = size > MIN_STEP_FRAC * math.sqrt(run.scale)
    if big.sum() < 4:
        return None
    small = size < float(np.median(size[big]))
    return small if (small & big).any() and (~small & big).any() else None


def _constant_bic(run: _Run, m: DynamicsModel) -> float:
    """BIC of a constant thrust on the model's effective sample size."""
    y = run.series.thrust_n
    rms = float(np.std(y))
    n_eff = effective_sample_size(m.n_samples, m.lag1_corr, 2.0)
    return n_eff * math.log(max(rms, 1e-150) ** 2) + math.log(n_eff)


def _tail_means(series: StepSeries, level: np.ndarray) -> np.ndarray:
    """Mean thrust over the last TAIL_FRAC of each hold (NaN for a hold without samples)."""
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


# ----- model-free step timings ----------------------------------------------------------------


def _step_metrics(series: StepSeries, level: np.ndarray, tails: np.ndarray, zero: float,
                  scale: float, steady: dict[float, float]) -> list[StepMetrics]:
    """Timings of every step larger than MIN_STEP_FRAC of full scale; `steady` (command ->
    mean thrust of its holds) gives each step's direction."""
    out = []
    for k in range(1, series.switch_s.size):
        a, b = float(tails[k - 1]), float(tails[k])
        if not (math.isfinite(a) and math.isfinite(b)) or abs(b - a) < MIN_STEP_FRAC * scale:
            continue
        pick = level == k
        t = series.t_s[pick] - series.switch_s[k]
        y = (series.thrust_n[pick] - zero - a) / (b - a)
        ends = [abs(steady.get(float(series.command[j]), 0.0)) for j in (k - 1, k)]
        out.append(_one_step(series, k, a, b, t, y, "up" if ends[1] > ends[0] else "down"))
    return out


def _one_step(series: StepSeries, k: int, a: float, b: float, t: np.ndarray,
              y: np.ndarray, direction: str) -> StepMetrics:
    """Timing of step k from its normalised response y (0 before, 1 at the new level)."""
    t10 = _first(t, y >= 0.1)
    t90 = _first(t, y >= 0.9)
    window = float(t[-1]) if t.size else 0.0
    settle, settled = _settling(t, y, window)
    return StepMetrics(float(series.command[k - 1]), float(series.command[k]), a, b,
                       direction, t10, t90 - t10, settle,
                       max(float(np.max(y)) - 1.0, 0.0), settled, window)


def _settling(t: np.ndarray, y: np.ndarray, window: float) -> tuple[float, bool]:
    """(settling time, settled): the response must stay in the band from then on, for at
    least SETTLED_FOR_FRAC of the window and 5 samples; otherwise it is censored (NaN)."""
    outside = np.flatnonzero(np.abs(y - 1) > BAND)
    if not outside.size:
        return 0.0, True
    first_in = int(outside[-1]) + 1
    if first_in >= t.size:
        return math.nan, False
    settle = float(t[first_in])
    if t.size - first_in < 5 or window - settle < SETTLED_FOR_FRAC * window:
        return math.nan, False
    return settle, True


def _first(t: np.ndarray, mask: np.ndarray) -> float:
    hit = np.flatnonzero(mask)
    return float(t[hit[0]]) if hit.size else math.nan
