"""Identify a vehicle's added mass and damping from free-running logs with known thrust.

Order of work: check the logs excite what is asked (else refuse, naming the parameter);
choose each DOF's damping structure by error on held-out segments; fit the per-DOF model,
then the coupled six-DOF model from it; intervals by a bootstrap over segments; predict
segments held out of every fit.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rigtool.analysis.vehicle import excitation
from rigtool.analysis.vehicle.fitting import (
    OutputFit,
    Problem,
    bootstrap,
    bounds,
    equation_error,
    global_search,
    output_error,
    residuals,
)
from rigtool.analysis.vehicle.model import (
    DOFS,
    NAMES,
    RigidBody,
    Segments,
    known_forces,
    regressors,
    simulate,
)
from rigtool.analysis.vehicle.segments import LogInput, Prepared, common_step, prepare
from rigtool.errors import UsageError
from rigtool.progress_hook import ProgressHook, no_progress

METHODS = ("ls", "nls", "global", "all")
STRUCTURES = {"linear+quadratic": (True, True), "quadratic": (False, True), "linear": (True, False)}
HOLD_OUT_EVERY = 5  # every fifth segment is held out of every fit
FOLDS = 4
SIMPLER_GAIN = 0.005  # a structure with a term less must predict this much better than both
FOLD_NFEV = 15  # a structure's held-out error needs its optimum roughly, not exactly
MIN_SEGMENTS = 10
DRAWS = 1000
GLOBAL_SEGMENTS = 24
UNRESOLVED = 1.0  # an interval half-width beyond this times |value| (and spanning 0): no value


@dataclass(frozen=True)
class Parameter:
    """One identified parameter: value and 95 % interval, or why there is none."""

    name: str
    value: float | None
    low: float | None
    high: float | None
    reason: str | None = None


@dataclass(frozen=True)
class HeldOut:
    """How well the model predicts segments no fit saw, per DOF."""

    dof: str
    rms: float
    range: float

    @property
    def percent(self) -> float:
        """RMS error as a percentage of the measured range."""
        return 100.0 * self.rms / self.range if self.range > 0 else float("nan")


@dataclass(frozen=True)
class Identification:
    """Everything the vehicle model, identification.json and the report need."""

    parameters: list[Parameter]
    dofs: list[str]
    method: str
    structures: dict[str, str]
    structure_errors: dict[str, dict[str, float]]
    estimates: dict[str, list[float]]  # method -> theta (18)
    global_agreement: float | None  # largest relative difference, global vs least squares
    held_out: list[HeldOut]
    trace_t_s: np.ndarray
    trace_measured: np.ndarray  # (traces, L, 6)
    trace_predicted: np.ndarray
    segments_fitted: int
    segments_held_out: int
    dt_s: float
    notes: list[str] = field(default_factory=list)


def _mask(dofs: np.ndarray, structure: dict[int, str]) -> np.ndarray:
    """Free parameters: added mass of each DOF, and its structure's damping terms."""
    free = np.zeros(18, dtype=bool)
    for i in np.flatnonzero(dofs):
        lin, quad = STRUCTURES[structure[i]]
        free[i], free[6 + i], free[12 + i] = True, lin, quad
    return free


def _problem(body: RigidBody, prep: Prepared, dofs: np.ndarray, free: np.ndarray) -> Problem:
    scale, lower, upper = bounds(body, prep)
    return Problem(body, dofs, free, scale, lower, upper, prep.smooth.std(axis=0) + 1e-12)


def _per_dof_sse(prob: Problem, theta: np.ndarray, seg: Segments) -> np.ndarray:
    """Output-error sum of squares per DOF (decoupled), over `seg`."""
    r = residuals(prob, theta[None], seg, coupled=False, fixed=theta)[0]
    out = np.zeros(6)
    out[prob.free_dofs] = np.sum(r**2, axis=(0, 1))
    return out


def _choose_structures(body: RigidBody, prep: Prepared, dofs: np.ndarray, train: np.ndarray,
                       progress: ProgressHook = no_progress
                       ) -> tuple[dict[int, str], dict[str, dict[str, float]]]:
    """Per DOF, the damping structure with the least held-out error over FOLDS folds (each
    fold's fit reported to `progress`)."""
    errors = {}
    task, n_fits = "damping-structure folds", len(STRUCTURES) * FOLDS
    progress(task, 0, n_fits)
    for k, name in enumerate(STRUCTURES):
        prob = _problem(body, prep, dofs, _mask(dofs, dict.fromkeys(range(6), name)))
        start = equation_error(prob, prep)
        total = np.zeros(6)
        for fold in range(FOLDS):
            fit_on = train[np.arange(len(train)) % FOLDS != fold]
            check = train[np.arange(len(train)) % FOLDS == fold]
            fit = output_error(prob, prep.segments.take(fit_on), start, coupled=False,
                               max_nfev=FOLD_NFEV)
            total += _per_dof_sse(prob, fit.theta, prep.segments.take(check))
            progress(task, k * FOLDS + fold + 1, n_fits)
        errors[name] = total
    chosen = {}
    for i in np.flatnonzero(dofs):
        best = min(STRUCTURES, key=lambda s, i=i: errors[s][i])
        full = errors["linear+quadratic"][i]
        chosen[i] = best if errors[best][i] < (1.0 - SIMPLER_GAIN) * full else "linear+quadratic"
    table = {DOFS[i]: {s: float(errors[s][i]) for s in STRUCTURES} for i in np.flatnonzero(dofs)}
    return chosen, table


def _global(prob: Problem, seg: Segments, base: np.ndarray, seed: int) -> tuple[np.ndarray, float]:
    """Differential evolution per DOF (the per-DOF costs are separate) on at most
    GLOBAL_SEGMENTS of the segments (its population is simulated at once), and how far its
    optimum lies from least squares' (from `base`) on the same segments and cost."""
    seg = seg.take(np.arange(len(seg))[:: max(1, -(-len(seg) // GLOBAL_SEGMENTS))])
    local = output_error(prob, seg, base, coupled=False).theta
    theta = base.copy()
    for i in np.flatnonzero(prob.free_dofs):
        only = np.zeros(6, dtype=bool)
        only[i] = True
        free = prob.free & np.isin(np.arange(18) % 6, [i])
        one = Problem(prob.body, only, free, prob.scale, prob.lower, prob.upper,
                      prob.velocity_scale)
        theta = global_search(one, seg, theta, seed + i, fixed=base)
    return theta, _agreement(theta, local, prob.free)


def _ls_intervals(prob: Problem, prep: Prepared, theta: np.ndarray, seed: int) -> np.ndarray:
    """Bootstrap of the equation-error fit over contiguous blocks of rows."""
    y = known_forces(prob.body, prep.tau, prep.smooth, prep.nu_dot, prep.attitude)
    phi = regressors(prep.smooth, prep.nu_dot)
    dofs = np.flatnonzero(prob.free_dofs)
    w = 1.0 / (y[:, dofs].std(axis=0) + 1e-12)
    a = phi[:, dofs][:, :, prob.free] * w[None, :, None] * prob.scale[prob.free]
    b = y[:, dofs] * w
    block = prep.segments.nu.shape[1]
    n_blocks = len(y) // block
    rows = a[: n_blocks * block].reshape(n_blocks, -1, a.shape[-1])
    ata = np.einsum("bmk,bml->bkl", rows, rows)
    atb = np.einsum("bmk,bm->bk", rows, b[: n_blocks * block].reshape(n_blocks, -1))
    rng = np.random.default_rng(seed)
    counts = rng.multinomial(n_blocks, np.full(n_blocks, 1.0 / n_blocks), size=DRAWS)
    out = np.repeat(theta[None], DRAWS, axis=0)
    for d, c in enumerate(counts):
        sol = np.linalg.lstsq(np.tensordot(c, ata, axes=1), np.tensordot(c, atb, axes=1),
                              rcond=None)[0]
        out[d, prob.free] = sol * prob.scale[prob.free]
    return out


def _parameters(theta: np.ndarray, draws: np.ndarray, free: np.ndarray, dofs: np.ndarray,
                structures: dict[int, str]) -> list[Parameter]:
    """Values and percentile intervals; absent terms and unresolved ones get a reason."""
    lo, hi = np.percentile(draws, [2.5, 97.5], axis=0)
    out = []
    for k, name in enumerate(NAMES):
        dof = k % 6
        if not dofs[dof]:
            out.append(Parameter(name, None, None, None, f"{DOFS[dof]} not identified (--dofs)"))
        elif not free[k]:
            out.append(Parameter(name, 0.0, None, None,
                                 f"assumed 0, not measured: not in the {structures[dof]} "
                                 f"structure chosen for {DOFS[dof]} by held-out error"))
        elif lo[k] < 0 < hi[k] and (hi[k] - lo[k]) / 2 > UNRESOLVED * abs(theta[k]):
            out.append(Parameter(name, None, float(lo[k]), float(hi[k]),
                                 f"not resolved by these logs: 95 % interval {lo[k]:.3g} to "
                                 f"{hi[k]:.3g} spans zero"))
        else:
            out.append(Parameter(name, float(theta[k]), float(lo[k]), float(hi[k])))
    return out


def identify(logs: list[LogInput], allocation: np.ndarray, body: RigidBody, dofs: list[int],
             method: str = "nls", seed: int = 1,
             progress: ProgressHook = no_progress) -> Identification:
    """The vehicle's hydrodynamic parameters from `logs`; UsageError when the logs cannot
    identify a parameter asked for, naming it and why. The structure folds and the final
    fits are reported to `progress`."""
    dt = common_step(logs)
    prep = prepare(logs, allocation, dt)
    n_seg = len(prep.segments)
    if n_seg < MIN_SEGMENTS:
        raise UsageError(f"the logs give {n_seg} segments of {prep.segments.nu.shape[1] * dt:g} s; "
                         f"identification needs at least {MIN_SEGMENTS} (longer logs)")
    problems = excitation.problems(prep, body.diagonal, dofs)
    if problems:
        raise UsageError("the logs cannot identify:\n  " + "\n  ".join(problems)
                         + "\n(fly the missing motions, or leave those DOFs out with --dofs)")
    mask = np.zeros(6, dtype=bool)
    mask[dofs] = True
    index = np.arange(n_seg)
    held = index[index % HOLD_OUT_EVERY == HOLD_OUT_EVERY - 1]
    train = index[index % HOLD_OUT_EVERY != HOLD_OUT_EVERY - 1]
    structures, structure_errors = _choose_structures(body, prep, mask, train, progress)
    progress("final fits", 0, 2)
    prob = _problem(body, prep, mask, _mask(mask, structures))
    fit_seg = prep.segments.take(train)
    estimates = {"ls": equation_error(prob, prep)}
    per_dof = output_error(prob, fit_seg, estimates["ls"], coupled=False)
    agreement = None
    if method in ("global", "all"):
        estimates["global"], agreement = _global(prob, fit_seg, estimates["ls"], seed)
    start = estimates["global"] if method == "global" else per_dof.theta
    progress("final fits", 1, 2)
    fit = output_error(prob, fit_seg, start, coupled=True)
    progress("final fits", 2, 2)
    estimates["nls"] = fit.theta
    chosen = estimates["ls"] if method == "ls" else fit.theta
    draws = (_ls_intervals(prob, prep, chosen, seed) if method == "ls"
             else bootstrap(fit, prob.free, DRAWS, seed))
    return _result(prob, prep, chosen, draws, structures, structure_errors, estimates,
                   agreement, method, held, train, dt)


def _agreement(a: np.ndarray, b: np.ndarray, free: np.ndarray) -> float:
    """Largest relative difference between two estimates over the free parameters."""
    return float(np.max(np.abs(a[free] - b[free]) / np.maximum(np.abs(b[free]), 1e-12)))


def _result(prob: Problem, prep: Prepared, theta: np.ndarray, draws: np.ndarray,
            structures: dict[int, str], structure_errors: dict, estimates: dict,
            agreement: float | None, method: str, held: np.ndarray, train: np.ndarray,
            dt: float) -> Identification:
    """Assemble the identification, with the held-out predictions of the coupled model."""
    seg = prep.segments.take(held)
    predicted = simulate(prob.body, theta[None], seg, prob.free_dofs, coupled=True)[0]
    held_out = []
    for i in np.flatnonzero(prob.free_dofs):
        err = predicted[:, 1:, i] - seg.nu[:, 1:, i]
        span = float(np.percentile(seg.nu[:, :, i], 99.5) - np.percentile(seg.nu[:, :, i], 0.5))
        held_out.append(HeldOut(DOFS[i], float(np.sqrt(np.mean(err**2))), span))
    traces = min(3, len(seg))
    return Identification(
        _parameters(theta, draws, prob.free, prob.free_dofs, structures),
        [DOFS[i] for i in np.flatnonzero(prob.free_dofs)], method,
        {DOFS[i]: s for i, s in structures.items()}, structure_errors,
        {k: [float(x) for x in v] for k, v in estimates.items()}, agreement, held_out,
        np.arange(seg.nu.shape[1]) * dt, seg.nu[:traces], predicted[:traces],
        len(train), len(held), dt)


__all__ = ["METHODS", "Identification", "LogInput", "OutputFit", "identify"]
