"""Logs made ready for identification: one time step, smoothed velocities and their slopes,
the thrusters' wrench, and equal segments (the unit of held-out checks and the bootstrap)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import savgol_coeffs, savgol_filter

from rigtool.analysis.vehicle.model import Segments
from rigtool.errors import UsageError

MAX_SMOOTH_S = 1.0  # the longest smoothing window tried
SEGMENT_S = 5.0


@dataclass(frozen=True)
class LogInput:
    """One log as analysis takes it: times, body velocities, roll and pitch, thrusts (N)."""

    source: str
    t_s: np.ndarray
    nu: np.ndarray
    attitude: np.ndarray
    thrust_n: np.ndarray  # N x thrusters, steady thrust of each command
    lag_s: np.ndarray  # per thruster: first-order time constant from command to thrust (0: none)


@dataclass(frozen=True)
class Prepared:
    """Every log on its own uniform grid, with the segments cut from them. The whole-log
    arrays are taken at the middle of each time step, where the thrust held over the step
    acts: velocities and attitude the mean of the step's ends, the acceleration their
    difference over the step (a central slope, no half-step slip against the thrust)."""

    nu: np.ndarray
    smooth: np.ndarray
    nu_dot: np.ndarray
    tau: np.ndarray
    attitude: np.ndarray
    noise: np.ndarray  # per-DOF standard deviation of the measured minus the smoothed
    segments: Segments


def _uniform(log: LogInput, dt: float) -> tuple[np.ndarray, ...]:
    """The log on a grid of step dt: velocities and attitude interpolated, thrusts held."""
    grid = np.arange(0.0, log.t_s[-1] + 0.5 * dt, dt)
    grid = grid[grid <= log.t_s[-1]]
    lin = [np.column_stack([np.interp(grid, log.t_s, col) for col in x.T])
           for x in (log.nu, log.attitude)]
    # the row in force at each grid time; a grid time a rounding error short of a row's
    # time belongs to that row
    held = np.clip(np.searchsorted(log.t_s, grid + 1e-6 * dt, side="right") - 1, 0,
                   len(log.t_s) - 1)
    return grid, lin[0], lin[1], _lagged(log.thrust_n[held], log.lag_s, dt)


def _lagged(thrust: np.ndarray, lag_s: np.ndarray, dt: float) -> np.ndarray:
    """Each thruster's held steady thrust after its lag, sampled at the middle of each step.
    The lag is first order on the propeller's speed (thrust ~ n|n|), so it acts on the
    signed root of the thrust, exact for a held command."""
    keep = np.exp(-dt / np.maximum(lag_s, 1e-9))
    mid = np.exp(-0.5 * dt / np.maximum(lag_s, 1e-9))
    root = np.sign(thrust) * np.sqrt(np.abs(thrust))
    out = np.empty_like(root)
    state = root[0].astype(float).copy()
    for k, target in enumerate(root):
        out[k] = target + (state - target) * mid
        state = target + (state - target) * keep
    return out * np.abs(out)


def _smoothed(nu: np.ndarray, dt: float) -> np.ndarray:
    """Each velocity through a cubic Savitzky-Golay filter whose window (5 samples to
    MAX_SMOOTH_S) minimises its generalised cross-validation score: noisy channels are
    smoothed over many samples, clean or fast ones hardly at all."""
    longest = max(min(int(MAX_SMOOTH_S / dt), len(nu) - 1), 5)
    best, best_score = nu.copy(), np.full(nu.shape[1], np.inf)
    for w in range(5, longest + 1, 2):
        smooth = savgol_filter(nu, w, 3, axis=0)
        score = np.mean((nu - smooth) ** 2, axis=0) / (1.0 - savgol_coeffs(w, 3)[w // 2]) ** 2
        better = score < best_score
        best[:, better], best_score[better] = smooth[:, better], score[better]
    return best


def prepare(logs: list[LogInput], allocation: np.ndarray, dt_s: float,
            segment_s: float = SEGMENT_S) -> Prepared:
    """Resample every log to `dt_s`, smooth, differentiate and cut into segments."""
    parts: dict[str, list] = {k: [] for k in ("nu", "smooth", "dot", "tau", "att", "residual")}
    seg: dict[str, list] = {k: [] for k in ("nu", "smooth", "tau", "att", "log", "start")}
    length = max(int(round(segment_s / dt_s)), 10)
    for index, log in enumerate(logs):
        grid, nu, att, thrust = _uniform(log, dt_s)
        if len(grid) < length:
            continue  # a part shorter than a segment (a log cut at its gaps) adds nothing
        smooth = _smoothed(nu, dt_s)
        tau = thrust @ allocation.T
        mids = (0.5 * (nu[1:] + nu[:-1]), 0.5 * (smooth[1:] + smooth[:-1]),
                np.diff(smooth, axis=0) / dt_s, tau[:-1], 0.5 * (att[1:] + att[:-1]))
        for key, value in zip(("nu", "smooth", "dot", "tau", "att"), mids, strict=True):
            parts[key].append(value)
        parts["residual"].append(nu - smooth)
        for s in range(0, len(grid) - length + 1, length):
            cut = slice(s, s + length)
            for key, value in zip(("nu", "smooth", "tau", "att"), (nu, smooth, tau, att),
                                  strict=True):
                seg[key].append(value[cut])
            seg["log"].append(index)
            seg["start"].append(grid[s])
    if not parts["nu"]:
        raise UsageError(f"no log (nor part of one between time gaps) lasts one {segment_s:g} s "
                         "segment")
    whole = {k: np.concatenate(v) for k, v in parts.items()}
    segments = Segments(dt_s, *(np.array(seg[k]) for k in ("nu", "smooth", "tau", "att")),
                        np.array(seg["log"]), np.array(seg["start"]))
    noise = whole["residual"].std(axis=0)
    return Prepared(whole["nu"], whole["smooth"], whole["dot"], whole["tau"], whole["att"],
                    noise, segments)


def common_step(logs: list[LogInput]) -> float:
    """The coarsest median sample step of the logs: no log is resampled finer than it was."""
    return max(float(np.median(np.diff(log.t_s))) for log in logs)
