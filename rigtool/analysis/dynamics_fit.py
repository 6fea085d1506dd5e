"""Least-squares fit of one dynamics model to a step-response run (rigtool/analysis/dynamics.py).

The parameter vector is [dynamics..., level thrusts..., sensor zero]. Time constants, alpha
and the reverse ratio are fitted as logarithms (always positive, no bounds needed); the delay
and the inflow gain as they are. Levenberg-Marquardt on the normal equations with a
finite-difference Jacobian evaluated for all columns at once (the response functions take a
batch of parameter vectors), so a fit of 25,000 samples takes a fraction of a second.
Samples may be left out of a fit (mask), which the held-out-step validation uses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rigtool.analysis.dynamics_response import ModelParams, thrust_response

DYN_NAMES = {"one-state": ("tau_n", "delay"), "two-state": ("tau_n", "delay", "tau_a", "g"),
             "yoerger": ("alpha", "delay"), "healey-lag": ("tau_n", "delay", "beta", "g"),
             "healey": ("alpha", "delay", "beta", "g"),
             "rise-fall": ("tau_n", "tau_fall", "delay")}
LOG_PARAMS = frozenset(("tau_n", "tau_a", "alpha", "rho", "beta", "tau_fall"))
MAX_ITER = 100
LOG_MIN, LOG_MAX = math.log(1e-4), math.log(1e3)  # range of time constants, alpha and rho
BATCH_ELEMENTS = 4_000_000  # samples x parameters evaluated at once in a Jacobian
REL_STEP = 1e-6
JUMP_TOL = 0.1  # forward and backward differences further apart than this: a jump
CHI2_TOL = 1e-3  # converged when a step lowers chi^2 (cost / residual variance) less


@dataclass(frozen=True)
class Problem:
    """The samples of a step run and the structure of one model's parameters."""

    kind: str
    t: np.ndarray  # (N,) sample times
    y: np.ndarray  # (N,) thrust
    switch: np.ndarray  # (K,) command times
    level_idx: np.ndarray  # (K,) index of each level's thrust parameter, -1 for neutral
    n_levels: int
    fit_rho: bool  # reverse ratio free (a step crosses zero) or 1
    grid_s: float = 0.0  # node spacing of the Healey inflow, fixed for the whole fit

    @property
    def names(self) -> tuple[str, ...]:
        """Names of the dynamics parameters, in vector order."""
        return DYN_NAMES[self.kind] + (("rho",) if self.fit_rho else ())

    @property
    def n_params(self) -> int:
        return len(self.names) + self.n_levels + 1


@dataclass
class FitResult:
    """A converged fit: natural parameters, residuals and Jacobian (natural parameters)."""

    theta: np.ndarray  # transformed parameter vector
    natural: np.ndarray  # dynamics in natural units, then levels, then zero
    residual: np.ndarray  # data minus model on every sample (masked ones included)
    jac: np.ndarray  # d model / d natural parameters on the fitted samples
    mask: np.ndarray  # samples the fit used
    converged: bool


def to_natural(problem: Problem, theta: np.ndarray) -> np.ndarray:
    """Transformed vector(s) -> natural units (exp of the log parameters)."""
    out = np.array(theta, dtype=float, copy=True)
    for j, name in enumerate(problem.names):
        if name in LOG_PARAMS:
            out[..., j] = np.exp(np.clip(out[..., j], LOG_MIN, LOG_MAX))
    return out


def to_theta(problem: Problem, natural: np.ndarray) -> np.ndarray:
    """Natural units -> transformed vector."""
    out = np.array(natural, dtype=float, copy=True)
    for j, name in enumerate(problem.names):
        if name in LOG_PARAMS:
            out[j] = math.log(max(out[j], 1e-12))
    return out


def predict(problem: Problem, natural: np.ndarray) -> np.ndarray:
    """Model thrust with sensor zero, (N,) for one vector or (B, N) for a batch."""
    nat = np.atleast_2d(natural)
    d = len(problem.names)
    col = {name: nat[:, j] for j, name in enumerate(problem.names)}
    lv = nat[:, d:d + problem.n_levels]
    levels = np.where(problem.level_idx[None, :] >= 0,
                      lv[:, np.clip(problem.level_idx, 0, None)], 0.0)
    p = ModelParams(problem.kind, tau_n=col.get("tau_n", 1.0), alpha=col.get("alpha", 1.0),
                    tau_a=col.get("tau_a", 1.0), gain=col.get("g", 0.0), delay=col["delay"],
                    rho=col.get("rho", 1.0), beta=col.get("beta", 1.0), grid_s=problem.grid_s,
                    tau_fall=col.get("tau_fall", 1.0))
    out = thrust_response(problem.t, problem.switch, levels, p) + nat[:, -1][:, None]
    return out if np.ndim(natural) > 1 else out[0]


def jacobian(problem: Problem, natural: np.ndarray, mask: np.ndarray, base: np.ndarray,
             two_sided: bool = False) -> np.ndarray:
    """d model / d natural parameter on the masked samples, forward differences in batches;
    `two_sided`: central differences, with 0 where the forward and backward ones disagree
    (a sample the response jumps at: the two-state thrust c(x) (x|x| + g (...)) jumps where
    the propeller passes zero while the inflow is not, and such a sample says nothing about
    the smooth dependence the covariance needs)."""
    steps = REL_STEP * np.maximum(np.abs(natural), _floor(problem, natural))
    forward = _differences(problem, natural, mask, base, steps)
    if not two_sided:
        return forward
    backward = _differences(problem, natural, mask, base, -steps)
    jump = np.abs(forward - backward) > JUMP_TOL * (np.abs(forward) + np.abs(backward)) + 1e-12
    return np.where(jump, 0.0, (forward + backward) / 2)


def _differences(problem: Problem, natural: np.ndarray, mask: np.ndarray, base: np.ndarray,
                 steps: np.ndarray) -> np.ndarray:
    """(model(natural + step e_j) - model) / step for every parameter j, in batches."""
    p = natural.size
    jac = np.empty((int(mask.sum()), p))
    jac[:, -1] = 1.0  # the sensor zero enters additively
    per = max(1, BATCH_ELEMENTS // max(problem.t.size, 1))
    for lo in range(0, p - 1, per):
        cols = np.arange(lo, min(lo + per, p - 1))
        batch = np.repeat(natural[None, :], cols.size, axis=0)
        batch[np.arange(cols.size), cols] += steps[cols]
        jac[:, cols] = ((predict(problem, batch)[:, mask] - base[mask]) / steps[cols, None]).T
    return jac


def _floor(problem: Problem, natural: np.ndarray) -> np.ndarray:
    """Smallest scale of each parameter for its difference step."""
    d = len(problem.names)
    lv = natural[d:d + problem.n_levels]
    scale = float(np.max(np.abs(lv))) if lv.size else 1.0
    floor = np.full(natural.size, 1e-3 * max(scale, 1e-9))
    floor[:d] = [1e-3 if n in ("delay", "g") else 1e-6 for n in problem.names]
    return floor


def fit(problem: Problem, natural0: np.ndarray, mask: np.ndarray | None = None,
        with_jacobian: bool = True, max_iter: int = MAX_ITER) -> FitResult:
    """Levenberg-Marquardt from `natural0` on the samples in `mask` (default: all); the
    Jacobian at the solution only `with_jacobian` (covariances need it, predictions do not)."""
    use = np.ones(problem.t.size, dtype=bool) if mask is None else mask
    y = problem.y[use]
    theta = to_theta(problem, natural0)
    nat = to_natural(problem, theta)
    model = predict(problem, nat)
    cost = _cost(y, model[use])
    lam, converged = 1e-3, False
    for _ in range(max_iter):
        jt = _theta_jacobian(problem, theta, nat, use, model)
        r = y - model[use]
        a, g = jt.T @ jt, jt.T @ r
        diag = np.maximum(np.diag(a), 1e-12 * max(float(np.max(np.diag(a))), 1e-300))
        improved = False
        for _ in range(12):
            step = _solve(a + lam * np.diag(diag), g)
            trial = theta + step
            trial_nat = to_natural(problem, trial)
            trial_model = predict(problem, trial_nat)
            trial_cost = _cost(y, trial_model[use])
            if math.isfinite(trial_cost) and trial_cost <= cost:
                improved = True
                break
            lam *= 4.0
        if not improved:
            converged = True
            break
        drop = cost - trial_cost
        theta, nat, model, cost = trial, trial_nat, trial_model, trial_cost
        lam = max(lam / 3.0, 1e-9)
        if drop < CHI2_TOL * cost / max(y.size - theta.size, 1):
            converged = True
            break
    jac = (jacobian(problem, nat, use, model, two_sided=True) if with_jacobian
           else np.empty((0, theta.size)))
    return FitResult(theta, nat, problem.y - model, jac, use, converged)


def _theta_jacobian(problem: Problem, theta: np.ndarray, nat: np.ndarray, use: np.ndarray,
                    model: np.ndarray) -> np.ndarray:
    """Jacobian in the transformed parameters (chain rule from the natural one)."""
    jac = jacobian(problem, nat, use, model)
    for j, name in enumerate(problem.names):
        if name in LOG_PARAMS:
            jac[:, j] *= nat[j]
    return jac


def _solve(a: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Solve a x = g, least-squares for a singular a."""
    try:
        return np.linalg.solve(a, g)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(a, g, rcond=None)[0]


def _cost(y: np.ndarray, model: np.ndarray) -> float:
    """Residual sum of squares (inf when the model is not finite)."""
    r = y - model
    value = float(np.einsum("i,i->", r, r))  # not BLAS: its threads stall on a busy machine
    return value if math.isfinite(value) else math.inf
