"""Logs made ready for identification: one time step, smoothed velocities and their slopes,
the thrusters' wrench, and equal segments (the unit of held-out checks and the bootstrap)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import savgol_filter

from rigtool.analysis.vehicle.model import Segments

SMOOTH_S = 0.6  # the smoothing window: longer than the noise, shorter than the vehicle's lags
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
    """Every log on its own uniform grid, concatenated, with the segments cut from them."""

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
    held = np.clip(np.searchsorted(log.t_s, grid, side="right") - 1, 0, len(log.t_s) - 1)
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


def _window(dt: float, n: int) -> int:
    """An odd Savitzky-Golay window of about SMOOTH_S, at least 5 samples, at most n."""
    w = max(5, int(round(SMOOTH_S / dt)) | 1)
    return min(w, n if n % 2 else n - 1)


def prepare(logs: list[LogInput], allocation: np.ndarray, dt_s: float,
            segment_s: float = SEGMENT_S) -> Prepared:
    """Resample every log to `dt_s`, smooth, differentiate and cut into segments."""
    parts: dict[str, list] = {k: [] for k in ("nu", "smooth", "dot", "tau", "att")}
    seg: dict[str, list] = {k: [] for k in ("nu", "smooth", "tau", "att", "log", "start")}
    length = max(int(round(segment_s / dt_s)), 10)
    for index, log in enumerate(logs):
        grid, nu, att, thrust = _uniform(log, dt_s)
        w = _window(dt_s, len(grid))
        smooth = savgol_filter(nu, w, 3, axis=0)
        dot = savgol_filter(nu, w, 3, deriv=1, delta=dt_s, axis=0)
        tau = thrust @ allocation.T
        for key, value in zip(("nu", "smooth", "dot", "tau", "att"),
                              (nu, smooth, dot, tau, att), strict=True):
            parts[key].append(value)
        for s in range(0, len(grid) - length + 1, length):
            cut = slice(s, s + length)
            for key, value in zip(("nu", "smooth", "tau", "att"), (nu, smooth, tau, att),
                                  strict=True):
                seg[key].append(value[cut])
            seg["log"].append(index)
            seg["start"].append(grid[s])
    whole = {k: np.concatenate(v) for k, v in parts.items()}
    segments = Segments(dt_s, *(np.array(seg[k]) for k in ("nu", "smooth", "tau", "att")),
                        np.array(seg["log"]), np.array(seg["start"]))
    noise = (whole["nu"] - whole["smooth"]).std(axis=0)
    return Prepared(whole["nu"], whole["smooth"], whole["dot"], whole["tau"], whole["att"],
                    noise, segments)


def common_step(logs: list[LogInput]) -> float:
    """The coarsest median sample step of the logs: no log is resampled finer than it was."""
    return max(float(np.median(np.diff(log.t_s))) for log in logs)
