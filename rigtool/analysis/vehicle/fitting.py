"""The three identification methods of the sources, on one model and one parameter vector.

- least squares on the equation error (the model is linear in its parameters once the
  accelerations are known; here they come from smoothed slopes, so noise biases it);
- nonlinear least squares on the output error: simulate each segment from its first state
  and fit the velocities (scipy.optimize.least_squares), started from the first;
- a global search on the same output error (scipy's differential_evolution, vectorised over
  its population), which needs no starting point.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import differential_evolution, least_squares

from rigtool.analysis.vehicle.model import RigidBody, Segments, known_forces, regressors, simulate
from rigtool.analysis.vehicle.segments import Prepared

FD_STEP = 1e-4  # finite-difference step, relative to each parameter's scale
DIVERGED = 1e3  # a scaled residual of a simulation that blew up (unstable parameters)


@dataclass(frozen=True)
class Problem:
    """What a fit may change: which DOFs are simulated and which parameters are free."""

    body: RigidBody
    free_dofs: np.ndarray  # bool (6,)
    free: np.ndarray  # bool (18,)
    scale: np.ndarray  # (18,) typical magnitude of each parameter
    lower: np.ndarray
    upper: np.ndarray
    velocity_scale: np.ndarray  # (6,) residuals are divided by these


def bounds(body: RigidBody, prep: Prepared) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(scale, lower, upper): added mass up to 4 rigid-body masses; damping up to 5 times
    what would balance the largest force at the largest velocity, and slightly positive."""
    force = known_forces(body, prep.tau, prep.smooth, prep.nu_dot, prep.attitude)
    f = np.percentile(np.abs(force - force.mean(axis=0)), 99, axis=0) + 1e-9
    v = np.percentile(np.abs(prep.smooth), 99, axis=0) + 1e-9
    scale = np.concatenate((body.diagonal, f / v, f / v**2))
    lower = np.concatenate((-4.0 * body.diagonal, -5.0 * f / v, -5.0 * f / v**2))
    upper = np.concatenate((np.zeros(6), 0.5 * f / v, 0.5 * f / v**2))
    return scale, lower, upper


def equation_error(prob: Problem, prep: Prepared) -> np.ndarray:
    """theta by weighted linear least squares on M_A nu' + C_A nu + D nu = known forces."""
    y = known_forces(prob.body, prep.tau, prep.smooth, prep.nu_dot, prep.attitude)
    phi = regressors(prep.smooth, prep.nu_dot)
    dofs = np.flatnonzero(prob.free_dofs)
    weight = 1.0 / (y[:, dofs].std(axis=0) + 1e-12)
    a = (phi[:, dofs][:, :, prob.free] * weight[None, :, None]).reshape(-1, prob.free.sum())
    b = (y[:, dofs] * weight).reshape(-1)
    cols = prob.scale[prob.free]
    solution = np.linalg.lstsq(a * cols, b, rcond=None)[0] * cols
    theta = np.zeros(18)
    theta[prob.free] = solution
    return theta


def residuals(prob: Problem, theta_sets: np.ndarray, seg: Segments, coupled: bool,
              fixed: np.ndarray | None = None) -> np.ndarray:
    """Scaled output errors (P, S, L-1, free DOFs) of each parameter set; per-DOF (not
    coupled), the Coriolis terms take their added masses from `fixed`."""
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        sim = simulate(prob.body, theta_sets, seg, prob.free_dofs, coupled, fixed)
    dofs = prob.free_dofs
    out = (sim[:, :, 1:, dofs] - seg.nu[None, :, 1:, dofs]) / prob.velocity_scale[dofs]
    return np.where(np.isfinite(out), np.clip(out, -DIVERGED, DIVERGED), DIVERGED)


def _full(prob: Problem, x: np.ndarray, base: np.ndarray) -> np.ndarray:
    """theta with the free parameters set from x (scaled), the others from base."""
    theta = np.array(base, dtype=float)
    theta[prob.free] = x * prob.scale[prob.free]
    return theta


@dataclass(frozen=True)
class OutputFit:
    """An output-error optimum: theta, its cost, and per-segment residuals and Jacobian."""

    theta: np.ndarray
    cost: float
    residual: np.ndarray  # (S, n) per segment
    jacobian: np.ndarray  # (S, n, free parameters), in theta's own units


def _jacobian(prob: Problem, theta: np.ndarray, seg: Segments, coupled: bool,
              fixed: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Residuals (S, n) at theta and their forward-difference Jacobian (S, n, k), all
    parameter sets simulated in one batch. Per-DOF, DOF i's residuals depend on its own
    three parameters only, so one set per role (added mass, linear, quadratic) perturbs all
    DOFs at once."""
    idx = np.flatnonzero(prob.free)
    steps = FD_STEP * np.maximum(np.abs(theta[idx]), prob.scale[idx])
    groups = [[k] for k in range(len(idx))] if coupled else [
        [k for k, j in enumerate(idx) if j // 6 == role] for role in range(3)]
    groups = [g for g in groups if g]
    sets = np.repeat(theta[None], len(groups) + 1, axis=0)
    for n, g in enumerate(groups):
        sets[n + 1, idx[g]] += steps[g]
    res = residuals(prob, sets, seg, coupled, fixed)
    base = res[0].reshape(len(seg), -1)
    dof_of_row = np.tile(np.flatnonzero(prob.free_dofs), res.shape[2])
    jac = np.zeros((*base.shape, len(idx)))
    for n, g in enumerate(groups):
        delta = res[n + 1].reshape(len(seg), -1) - base
        for k in g:
            rows = dof_of_row == idx[k] % 6 if not coupled else slice(None)
            jac[:, rows, k] = delta[:, rows] / steps[k]
    return base, jac


def output_error(prob: Problem, seg: Segments, start: np.ndarray, coupled: bool,
                 max_nfev: int = 40) -> OutputFit:
    """theta minimising the output error, from `start` (clipped into the bounds)."""
    k = prob.free
    lo, hi = prob.lower[k] / prob.scale[k], prob.upper[k] / prob.scale[k]
    x0 = np.clip(start[k] / prob.scale[k], lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))

    fixed = None if coupled else start

    def fun(x: np.ndarray) -> np.ndarray:
        return residuals(prob, _full(prob, x, start)[None], seg, coupled, fixed).reshape(-1)

    def jac(x: np.ndarray) -> np.ndarray:
        _, j = _jacobian(prob, _full(prob, x, start), seg, coupled, fixed)
        return j.reshape(-1, j.shape[-1]) * prob.scale[k]

    sol = least_squares(fun, x0, jac=jac, bounds=(lo, hi), x_scale="jac", xtol=1e-8,
                        ftol=1e-10, max_nfev=max_nfev)
    theta = _full(prob, sol.x, start)
    res, j = _jacobian(prob, theta, seg, coupled, fixed)
    return OutputFit(theta, float(np.sum(res**2)), res, j)


def global_search(prob: Problem, seg: Segments, base: np.ndarray, seed: int,
                  fixed: np.ndarray, maxiter: int = 60) -> np.ndarray:
    """theta from differential evolution over the bounds (no starting point), the per-DOF
    output error as cost (Coriolis added masses from `fixed`); the other parameters stay at
    `base`."""
    k = prob.free

    def cost(x: np.ndarray) -> np.ndarray:
        sets = np.repeat(base[None], x.shape[1], axis=0)
        sets[:, k] = (x * prob.scale[k][:, None]).T
        r = residuals(prob, sets, seg, coupled=False, fixed=fixed)
        return np.sum(r.reshape(len(sets), -1) ** 2, axis=1)

    sol = differential_evolution(
        cost, list(zip(prob.lower[k] / prob.scale[k], prob.upper[k] / prob.scale[k], strict=True)),
        seed=seed, maxiter=maxiter, popsize=10, tol=1e-7, polish=False, vectorized=True,
        updating="deferred")
    return _full(prob, sol.x, base)


def bootstrap(fit: OutputFit, free: np.ndarray, draws: int, seed: int) -> np.ndarray:
    """theta for `draws` resamplings of the segments (with replacement), each one
    Gauss-Newton step from the optimum; (draws, 18)."""
    rng = np.random.default_rng(seed)
    a = np.einsum("snk,snl->skl", fit.jacobian, fit.jacobian)
    b = np.einsum("snk,sn->sk", fit.jacobian, fit.residual)
    n_seg = a.shape[0]
    out = np.repeat(fit.theta[None], draws, axis=0)
    counts = rng.multinomial(n_seg, np.full(n_seg, 1.0 / n_seg), size=draws)
    for d, w in enumerate(counts):
        step = np.linalg.lstsq(np.tensordot(w, a, axes=1), np.tensordot(w, b, axes=1),
                               rcond=None)[0]
        out[d, free] -= step
    return out
