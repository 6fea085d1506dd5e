"""Command curves: thrust vs command, dead zones, saturation, break-aways, branches, inverse LUT.

Works on the per-command aggregate of the steady-state point means (repeats and sweep
directions pooled), after removing the sensor zero (offset and drift since the tare, given by
the model fit, or fitted here to the dead points). A command is dead when its thrust is
statistically indistinguishable from zero: |mean| < max(k_se * SE, floor), the floor being the
largest of a fixed sensor floor, k_tare times the zero scatter between tare events, and k_zero
times the dead points' own scatter about zero. Live commands form branches (maximal runs of
live commands with one thrust sign); each branch gets a monotone (isotonic, piecewise-linear
between points) fit in its own direction, a saturated range at its extreme end, break-away
jumps, and an inverse lookup table over its usable part.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from rigtool.analysis.fits import LinearFit, ZeroLine, wls

CURVE_UNITS = ("pwm_counts", "pulse_us", "percent")
ZERO_PASSES = 4
MIN_ZERO_POINTS = 5  # dead commands needed to judge the zero's scatter
JUMP_SIDE = 3  # points each side of a gap that define the local lines of the break-away test
JUMP_LEVERAGE = 2.0  # variance inflation of a line extrapolated half a step past its points
OUTLIER_K = 5.0
DRIFT_K = 3.0  # a zero drift is kept when it exceeds this many standard errors  # zero-line points further than this many robust SDs from the line are dropped


@dataclass(frozen=True)
class CurveParams:
    """Detector thresholds (recorded in calibration.json)."""

    k_se: float = 4.0
    floor_n: float = 0.005
    k_tare: float = 3.0
    k_zero: float = 3.0
    isolated_factor: float = 3.0
    sat_frac: float = 0.05
    sat_slope_frac: float = 0.25
    min_sat_points: int = 3
    jump_ratio: float = 2.0
    jump_frac: float = 0.02
    jump_k_se: float = 8.0
    speed_floor_frac: float = 0.005  # with speed feedback: slower than this x the top is stopped


@dataclass
class Branch:
    """A run of live commands with one thrust direction.

    slope_sign is +1 when thrust rises with the command. `inverted` means |thrust| grows
    towards the neutral command instead of away from it (the STM32 forward branch).
    """

    direction: str
    command_lo: float
    command_hi: float
    slope_sign: int
    inverted: bool
    command: np.ndarray
    thrust_fit_n: np.ndarray
    saturated: tuple[float, float] | None
    usable: tuple[float, float] | None
    break_aways: list[float]
    lut_thrust_n: np.ndarray
    lut_command: np.ndarray


@dataclass
class CommandCurve:
    """Per-command aggregate and everything found on it; arrays are sorted by command.

    Thrust values are relative to `zero` (the sensor zero at each point's time), if any.
    """

    command_unit: str
    neutral_command: float
    floor_n: float
    zero: ZeroLine | None
    command: np.ndarray
    n_points: np.ndarray
    thrust_mean_n: np.ndarray
    thrust_se_n: np.ndarray
    thrust_min_n: np.ndarray
    thrust_max_n: np.ndarray
    speed_mean_rpm: np.ndarray
    current_mean_a: np.ndarray
    thrust_fit_n: np.ndarray
    state: np.ndarray
    branch: np.ndarray
    branches: list[Branch] = field(default_factory=list)
    dead_zones: list[tuple[float, float]] = field(default_factory=list)
    saturated: list[tuple[float, float]] = field(default_factory=list)
    break_aways: list[float] = field(default_factory=list)

    def is_dead(self, commands: np.ndarray) -> np.ndarray:
        """True for commands that fall inside a dead zone."""
        c = np.asarray(commands, dtype=float)
        out = np.zeros(c.shape, dtype=bool)
        for lo, hi in self.dead_zones:
            out |= (c >= lo) & (c <= hi)
        return out

    @property
    def lut(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Inverse LUT over all branches: (thrust_n, command, branch index), by branch then thrust."""
        parts = [(b.lut_thrust_n, b.lut_command, np.full(b.lut_command.size, i))
                 for i, b in enumerate(self.branches)]
        if not parts:
            return np.zeros(0), np.zeros(0), np.zeros(0, dtype=int)
        thrust, command, branch = (np.concatenate(p) for p in zip(*parts, strict=True))
        order = np.lexsort((thrust, branch))
        return thrust[order], command[order], branch[order]


def aggregate(command: np.ndarray, mean: np.ndarray, se: np.ndarray, lo: np.ndarray,
              hi: np.ndarray, *others: np.ndarray) -> tuple[np.ndarray, ...]:
    """Pool points per command: (command, count, mean, se, min, max, *mean of others).

    The pooled SE is the larger of the propagated per-point SEs and the scatter of the
    point means across repeats, so repeat-to-repeat variation counts as noise.
    """
    ok = np.isfinite(mean)
    cmd, inv = np.unique(command[ok], return_inverse=True)
    k = np.bincount(inv, minlength=cmd.size).astype(float)

    def avg(v: np.ndarray) -> np.ndarray:
        vv = v[ok]
        good = np.isfinite(vv)
        with np.errstate(invalid="ignore", divide="ignore"):
            return (np.bincount(inv, weights=np.where(good, vv, 0.0), minlength=cmd.size)
                    / np.bincount(inv, weights=good, minlength=cmd.size))

    m = avg(mean)
    se_prop = np.sqrt(np.bincount(inv, weights=np.nan_to_num(se[ok]) ** 2, minlength=cmd.size)) / k
    dev2 = np.bincount(inv, weights=(mean[ok] - m[inv]) ** 2, minlength=cmd.size)
    with np.errstate(invalid="ignore", divide="ignore"):
        se_rep = np.where(k > 1, np.sqrt(dev2 / np.maximum(k - 1, 1) / k), 0.0)
    mins = np.full(cmd.size, np.inf)
    maxs = np.full(cmd.size, -np.inf)
    np.fmin.at(mins, inv, lo[ok])
    np.fmax.at(maxs, inv, hi[ok])
    mins[~np.isfinite(mins)] = np.nan
    maxs[~np.isfinite(maxs)] = np.nan
    return (cmd, k.astype(int), m, np.maximum(se_prop, se_rep), mins, maxs,
            *(avg(v) for v in others))


def find_dead(mean: np.ndarray, se: np.ndarray, floor_n: float, params: CurveParams) -> np.ndarray:
    """Dead mask over commands sorted ascending; isolated marginal live points count as dead."""
    threshold = np.maximum(params.k_se * np.nan_to_num(se), floor_n)
    dead = np.abs(mean) < threshold
    inner = np.arange(1, mean.size - 1)
    isolated = (~dead[inner] & dead[inner - 1] & dead[inner + 1]
                & (np.abs(mean[inner]) < params.isolated_factor * threshold[inner]))
    dead[inner[isolated]] = True
    return dead


def ranges(command: np.ndarray, mask: np.ndarray) -> list[tuple[float, float]]:
    """Contiguous runs of True in `mask` as (first command, last command)."""
    out = []
    for start, stop in _runs(mask):
        out.append((float(command[start]), float(command[stop - 1])))
    return out


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    padded = np.concatenate(([False], mask, [False])).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def command_curve(command: np.ndarray, t_s: np.ndarray, thrust_mean: np.ndarray,
                  thrust_se: np.ndarray, thrust_min: np.ndarray, thrust_max: np.ndarray,
                  speed_mean: np.ndarray, current_mean: np.ndarray, *, command_unit: str,
                  neutral_command: float, zero: ZeroLine | None = None,
                  zero_scatter_n: float | None = None, speed_se: np.ndarray | None = None,
                  params: CurveParams | None = None) -> CommandCurve:
    """Analyse thrust vs command of one depth's points (one entry per point, any order).

    Thrust is taken relative to `zero` (offset + drift of the sensor zero at each point's
    time t_s); without one, the zero is estimated from the dead points themselves. Where the
    propeller speed is measured (signed, `speed_se` its standard errors), a command is dead
    when the propeller does not turn, and branches follow the direction it turns: near a
    deadband the thrust is too small to tell either.
    """
    p = params or CurveParams()
    floor = max(p.floor_n, p.k_tare * zero_scatter_n if zero_scatter_n else 0.0)
    line = zero or _zero_from_dead_points(command, t_s, thrust_mean, thrust_se, floor, p)
    z = line.at(t_s) if line else np.zeros(command.size)
    var_z = line.var_at(t_s) if line else np.zeros(command.size)
    n_se = np.full(command.size, np.nan) if speed_se is None else speed_se
    cmd, k, m, se, lo, hi, spd, cur, var_zero, spd_se = aggregate(
        command, thrust_mean - z, thrust_se, thrust_min - z, thrust_max - z, speed_mean,
        current_mean, var_z, n_se)
    se_dead = np.sqrt(se**2 + var_zero)  # a point is dead if zero within the zero's own error
    dead = find_dead(m, se_dead, floor, p)
    if dead.sum() >= MIN_ZERO_POINTS:
        # The dead points' own scatter about zero shows how well the zero is known.
        floor = max(floor, p.k_zero * 1.4826 * float(np.median(np.abs(m[dead]))))
        dead = find_dead(m, se_dead, floor, p)
    direction = np.sign(m)
    if np.isfinite(spd).all() and np.any(spd != 0):
        turning = np.abs(spd) > np.maximum(p.k_se * np.nan_to_num(spd_se),
                                           p.speed_floor_frac * float(np.max(np.abs(spd))))
        dead = ~turning
        direction = np.where(spd != 0, np.sign(spd), direction)
    state = np.where(dead, "dead", "live").astype("<U9")
    branch_of = np.full(cmd.size, -1)
    fit = np.zeros(cmd.size)
    branches = []
    for start, stop in _live_segments(direction, dead):
        sl = slice(start, stop)
        b = _branch(cmd[sl], m[sl], se[sl], neutral_command, p)
        branch_of[sl] = len(branches)
        fit[sl] = b.thrust_fit_n
        if b.saturated:
            state[sl][(cmd[sl] >= b.saturated[0]) & (cmd[sl] <= b.saturated[1])] = "saturated"
        branches.append(b)
    return CommandCurve(
        command_unit=command_unit, neutral_command=neutral_command, floor_n=floor, zero=line,
        command=cmd, n_points=k, thrust_mean_n=m, thrust_se_n=se, thrust_min_n=lo,
        thrust_max_n=hi, speed_mean_rpm=spd, current_mean_a=cur, thrust_fit_n=fit, state=state,
        branch=branch_of, branches=branches, dead_zones=ranges(cmd, dead),
        saturated=[b.saturated for b in branches if b.saturated],
        break_aways=sorted(c for b in branches for c in b.break_aways),
    )


def _zero_from_dead_points(command: np.ndarray, t_s: np.ndarray, mean: np.ndarray,
                           se: np.ndarray, floor: float, p: CurveParams) -> ZeroLine | None:
    """Sensor zero (offset + linear drift in time) read from every dead zone, iterated.

    Each pass finds the dead commands relative to the current zero line, allowing for the
    line's own uncertainty at each point's time, then fits the line through all their points
    (weighted, serially correlated errors, gross outliers such as a zone's live edge dropped).
    A zone far in time from the others is judged with the drift the others show, so a second
    zone that sits above the first zone's level is found, and then steadies the drift.
    """
    ok = np.isfinite(mean) & np.isfinite(t_s)
    line = None
    previous = None
    for _ in range(ZERO_PASSES):
        z = line.at(t_s) if line else np.zeros(command.size)
        var = line.var_at(t_s) if line else np.zeros(command.size)
        cmd, _k, m, s, _lo, _hi, var_zero = aggregate(command[ok], (mean - z)[ok], se[ok],
                                                      mean[ok], mean[ok], var[ok])
        s = np.sqrt(s**2 + var_zero)
        dead = find_dead(m, s, floor, p)
        if dead.sum() >= MIN_ZERO_POINTS:
            scatter = p.k_zero * 1.4826 * float(np.median(np.abs(m[dead])))
            dead = find_dead(m, s, max(floor, scatter), p)
        pts = ok & np.isin(command, _zone_cores(cmd, dead))
        if not pts.any() or (previous is not None and np.array_equal(pts, previous)):
            break
        previous = pts
        line = _fit_zero_line(t_s[pts], mean[pts], se[pts])
    return line


def _zone_cores(cmd: np.ndarray, dead: np.ndarray) -> np.ndarray:
    """Dead commands away from their zone's edges, where live thrust can leak into the zone.

    A zone of four or more commands keeps its inner half; shorter zones are kept whole.
    """
    keep = []
    for start, stop in _runs(dead):
        size = stop - start
        cut = size // 4 if size >= 4 else 0
        keep.append(cmd[start + cut:stop - cut])
    return np.concatenate(keep) if keep else np.zeros(0)


def _fit_zero_line(t: np.ndarray, y: np.ndarray, se: np.ndarray) -> ZeroLine:
    """Offset, plus a drift when it is significant (zone cores only, so a drift read from one
    zone swept in one direction is not the thrust leaking in at its edges)."""
    t_ref = float(np.mean(t))
    fit = _robust_wls(np.ones((t.size, 1)), y, se, t)
    if t.size >= 4 and np.ptp(t) > 0:
        sloped = _robust_wls(np.column_stack([np.ones(t.size), t - t_ref]), y, se, t)
        if abs(sloped.beta[1]) > DRIFT_K * math.sqrt(max(sloped.cov[1, 1], 0.0)):
            c = sloped.cov
            return ZeroLine(float(sloped.beta[0]), float(sloped.beta[1]), t_ref, "dead zones",
                            ((float(c[0, 0]), float(c[0, 1])), (float(c[1, 0]), float(c[1, 1]))))
    return ZeroLine(float(fit.beta[0]), 0.0, t_ref, "dead zones",
                    ((float(fit.cov[0, 0]), 0.0), (0.0, 0.0)))


def _robust_wls(design: np.ndarray, y: np.ndarray, se: np.ndarray, t: np.ndarray) -> LinearFit:
    """wls with points further than OUTLIER_K robust SDs from the line dropped (refitted once)."""
    keep = np.ones(y.size, dtype=bool)
    fit = wls(design, y, se, t)
    for _ in range(2):
        resid = y - design @ fit.beta
        scale = 1.4826 * float(np.median(np.abs(resid[keep]))) or float(np.std(resid[keep]))
        now = np.abs(resid) <= max(OUTLIER_K * scale, 1e-12)
        if now.sum() < design.shape[1] + 1 or np.array_equal(now, keep):
            break
        keep = now
        fit = wls(design[keep], y[keep], se[keep], t[keep])
    return fit


def _live_segments(direction: np.ndarray, dead: np.ndarray) -> list[tuple[int, int]]:
    """Runs of live commands, split where the direction (sign of thrust or speed) changes."""
    out = []
    for start, stop in _runs(~dead):
        sign = direction[start:stop]
        cuts = np.flatnonzero(sign[1:] != sign[:-1]) + 1
        bounds = [0, *cuts.tolist(), stop - start]
        out.extend((start + a, start + b) for a, b in zip(bounds[:-1], bounds[1:], strict=True))
    return out


def _branch(cmd: np.ndarray, m: np.ndarray, se: np.ndarray, neutral: float,
            p: CurveParams) -> Branch:
    from scipy.optimize import isotonic_regression  # on use; sklearn's costs 1.9 s more to import

    sign = 1 if np.nanmedian(m) > 0 else -1
    away = 1 if np.mean(cmd) >= neutral else -1
    slope = np.polyfit(cmd, m, 1)[0] if cmd.size >= 2 else 0.0
    slope_sign = int(np.sign(slope)) or sign * away
    weights = 1.0 / np.maximum(np.nan_to_num(se, nan=np.inf), 1e-6 * np.max(np.abs(m)) + 1e-12) ** 2
    g = isotonic_regression(m, weights=weights, increasing=slope_sign > 0).x
    saturated_idx = _saturated(cmd, g, se, p)
    live = np.ones(cmd.size, dtype=bool)
    saturated = None
    if saturated_idx is not None:
        live[saturated_idx[0]:saturated_idx[1]] = False
        saturated = (float(cmd[saturated_idx[0]]), float(cmd[saturated_idx[1] - 1]))
    usable = (float(cmd[live].min()), float(cmd[live].max())) if live.any() else None
    lut_f, lut_c = _inverse(cmd[live], g[live])
    return Branch(
        direction="forward" if sign > 0 else "reverse",
        command_lo=float(cmd[0]), command_hi=float(cmd[-1]), slope_sign=slope_sign,
        inverted=slope_sign * sign * away < 0, command=cmd, thrust_fit_n=g, saturated=saturated,
        usable=usable, break_aways=_break_aways(cmd, m, se, p), lut_thrust_n=lut_f,
        lut_command=lut_c,
    )


def _saturated(cmd: np.ndarray, g: np.ndarray, se: np.ndarray,
               p: CurveParams) -> tuple[int, int] | None:
    """Index range [a, b) of the flat run at the branch's |thrust| extreme, if any."""
    n = cmd.size
    if n < p.min_sat_points + 1:
        return None
    mag = np.abs(g)
    span = float(mag.max() - mag.min())
    if span <= 0:
        return None
    end = 0 if mag[0] >= mag[-1] else n - 1
    tol = max(p.sat_frac * span, p.k_se * float(np.nan_to_num(se[end])))
    close = np.abs(g - g[end]) <= tol
    order = range(n) if end == 0 else range(n - 1, -1, -1)
    run = 0
    for i in order:
        if not close[i]:
            break
        run += 1
    if run < p.min_sat_points or run == n:
        return None
    inner = run - 1 if end == 0 else n - run
    run_slope = abs(g[end] - g[inner]) / abs(cmd[end] - cmd[inner])
    branch_slope = span / abs(cmd[-1] - cmd[0])
    if run_slope > p.sat_slope_frac * branch_slope:
        return None
    return (0, run) if end == 0 else (n - run, n)


class _SideLine(NamedTuple):
    """A local line through the points on one side of a gap: level at x_ref, slope, and the
    variance of its value extrapolated to the gap's middle."""

    level: float
    slope: float
    var: float
    x_ref: float

    def at(self, x: float) -> float:
        return self.level + self.slope * (x - self.x_ref)


def _break_aways(cmd: np.ndarray, m: np.ndarray, se: np.ndarray, p: CurveParams) -> list[float]:
    """Commands where thrust steps between two points by more than the neighbours explain.

    Lines through up to `JUMP_SIDE` points on each side of a gap are extrapolated to its
    middle; their difference is the jump. It counts when it exceeds `jump_k_se` times its
    noise (the neighbours' scatter about their lines, or their standard errors, whichever is
    larger), `jump_ratio` times what the steeper side's slope covers in one step (a kink such
    as a saturation knee differs at mid-gap by at most half a step's slope, a jump by far
    more), and `jump_frac` of the branch's largest |thrust|.
    """
    out = []
    se0 = np.nan_to_num(se)
    floor = p.jump_frac * float(np.max(np.abs(m))) if m.size else 0.0
    for i in range(cmd.size - 1):
        left = slice(max(i + 1 - JUMP_SIDE, 0), i + 1)
        right = slice(i + 1, min(i + 1 + JUMP_SIDE, cmd.size))
        lf = _side_line(cmd[left], m[left], se0[left])
        rf = _side_line(cmd[right], m[right], se0[right])
        if lf is None and rf is None:
            continue
        # A side with one point takes the other side's slope.
        lf = lf or _SideLine(m[i], rf.slope, se0[i] ** 2, cmd[i])
        rf = rf or _SideLine(m[i + 1], lf.slope, se0[i + 1] ** 2, cmd[i + 1])
        mid = (cmd[i] + cmd[i + 1]) / 2
        jump = rf.at(mid) - lf.at(mid)
        step_cover = max(abs(lf.slope), abs(rf.slope)) * (cmd[i + 1] - cmd[i])
        if abs(jump) > max(p.jump_k_se * math.sqrt(lf.var + rf.var), p.jump_ratio * step_cover,
                           floor):
            out.append(float(cmd[i + 1] if abs(m[i + 1]) >= abs(m[i]) else cmd[i]))
    return out


def _side_line(x: np.ndarray, y: np.ndarray, se: np.ndarray) -> _SideLine | None:
    """The line through 2-3 points on one side of a gap (None for fewer than two)."""
    if x.size < 2:
        return None
    x_ref = float(np.mean(x))
    slope, level = np.polyfit(x - x_ref, y, 1)
    resid = y - (level + slope * (x - x_ref))
    dof = x.size - 2
    scatter = float(np.sum(resid**2) / dof) if dof > 0 else 0.0
    var_point = max(scatter, float(np.mean(se**2)))
    return _SideLine(float(level), float(slope), var_point / x.size * JUMP_LEVERAGE, x_ref)


def _inverse(cmd: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Knots of command(thrust) from the monotone fit; tied thrusts collapse to their mid command."""
    if cmd.size == 0:
        return np.zeros(0), np.zeros(0)
    thrust, inv = np.unique(g, return_inverse=True)
    lo = np.full(thrust.size, np.inf)
    hi = np.full(thrust.size, -np.inf)
    np.minimum.at(lo, inv, cmd)
    np.maximum.at(hi, inv, cmd)
    return thrust, (lo + hi) / 2
