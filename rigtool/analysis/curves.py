"""Command curves: thrust vs command, dead zones, saturation, break-aways, branches, inverse LUT.

Works on the per-command aggregate of the steady-state point means (repeats and sweep
directions pooled), after removing the sensor zero (offset and drift since the tare, given by
the model fit, or found here together with the dead points, anchored at the tare: see
zero_search.py). A command is dead when its thrust is
statistically indistinguishable from zero: |mean| < max(k_se * SE, floor), the floor being the
largest of a fixed sensor floor, k_tare times the zero scatter between tare events, and k_zero
times the dead points' own scatter about zero. Live commands form branches (maximal runs of
live commands with one thrust sign); each branch gets a monotone (isotonic, piecewise-linear
between points) fit in its own direction, a saturated range at its extreme end, break-away
jumps, and an inverse lookup table over its usable part. Live commands beside a dead zone that
the data cannot tell from it (a drift could make them read zero instead) are counted as dead
and named in `CommandCurve.warnings`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from rigtool.analysis.fits import ZeroLine
from rigtool.analysis.zero_search import (
    NO_ANCHORS,
    Anchors,
    Imitation,
    ZeroPoints,
    fit_zero_line,
    imitations,
    runs,
    search_zero,
    section_anchors,
    zone_cores,
)

CURVE_UNITS = ("pwm_counts", "pulse_us", "percent", "volts")
ZERO_PASSES = 4
MIN_ZERO_POINTS = 5  # dead commands needed to judge the zero's scatter
JUMP_SIDE = 3  # points each side of a gap that define the local lines of the break-away test
JUMP_LEVERAGE = 2.0  # variance inflation of a line extrapolated half a step past its points


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
    warnings: list[str] = field(default_factory=list)  # zero/dead-zone doubts, naming commands
    # Per side of neutral ("forward"/"reverse" by command side: "above"/"below"), where the
    # motor starts from rest and where it stops coming back, when those differ (start_stop).
    start_stop: dict[str, tuple[float, float]] = field(default_factory=dict)

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
    return [(float(command[start]), float(command[stop - 1])) for start, stop in runs(mask)]


def command_curve(command: np.ndarray, t_s: np.ndarray, thrust_mean: np.ndarray,
                  thrust_se: np.ndarray, thrust_min: np.ndarray, thrust_max: np.ndarray,
                  speed_mean: np.ndarray, current_mean: np.ndarray, *, command_unit: str,
                  neutral_command: float, zero: ZeroLine | None = None,
                  zero_scatter_n: float | None = None, speed_se: np.ndarray | None = None,
                  params: CurveParams | None = None, tare_t_s: np.ndarray | None = None,
                  tare_drift: tuple[float, float] | None = None,
                  sessions: tuple[float, ...] = (), drifts: bool = True,
                  sweep: np.ndarray | None = None, zero_at_neutral: bool = False,
                  law: Callable[[np.ndarray], np.ndarray] | None = None) -> CommandCurve:
    """Analyse thrust vs command of one depth's points (one entry per point, any order).

    Thrust is taken relative to `zero` (the sensor zero at each point's time t_s); without
    one, the zero and the dead points are found together (zero_search.py), anchored at the
    tares (`tare_t_s`; `tare_drift` (N/s, SE) when they show one) or the neutral command; a
    resumed run's `sessions` each get their own offset, with one drift. With speed (signed,
    `speed_se` its errors) a command is dead when the propeller does not turn, and branches
    follow its direction. Live commands beside a dead zone that a drift could equally make
    dead are counted as dead and named in `warnings`. `drifts` False (drift_design.py): the
    zero is flat. `sweep` ("up"/"down" per point): where the motor starts from rest further
    from neutral than it stops coming back, the inverse table keeps only commands that start
    it. `zero_at_neutral` (no speed): the line runs through the neutral command's points
    alone (a ramp's neutral ends: its bins, read once each, would pass for a drift).
    `law` (signed speed -> signed thrust relative to the zero): points read once each (a
    table's rows) scatter by their full noise, so each branch follows the fitted thrust law at
    its points' speeds, which pools every point, instead of the points themselves.
    """
    p = params or CurveParams()
    floor = max(p.floor_n, p.k_tare * zero_scatter_n if zero_scatter_n else 0.0)
    ok = np.isfinite(thrust_mean) & np.isfinite(t_s)
    pts = ZeroPoints(command[ok], t_s[ok], thrust_mean[ok], np.nan_to_num(thrust_se[ok]))
    anchors = section_anchors(tare_t_s, t_s, tare_drift, sessions)
    if not drifts:
        anchors = dataclasses.replace(anchors, drift=None, drifts=False)
    hint = _not_turning(speed_mean[ok], None if speed_se is None else speed_se[ok], p)
    if hint is None and zero_at_neutral:
        hint = command[ok] == neutral_command
    line = zero or _find_zero(pts, anchors, hint, neutral_command, floor, p)
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
    notes: list[str] = []
    if np.isfinite(spd).all() and np.any(spd != 0):
        turning = np.abs(spd) > np.maximum(p.k_se * np.nan_to_num(spd_se),
                                           p.speed_floor_frac * float(np.max(np.abs(spd))))
        dead = ~turning
        direction = np.where(spd != 0, np.sign(spd), direction)
    elif zero is None and line is not None and drifts:
        dead, notes = _imitated(pts, anchors, cmd, dead, floor, neutral_command, command_unit, p)
    state = np.where(dead, "dead", "live").astype("<U9")
    branch_of = np.full(cmd.size, -1)
    fit = np.zeros(cmd.size)
    branches = []
    for start, stop in _live_segments(direction, dead):
        sl = slice(start, stop)
        target = None if law is None else law(spd[sl])
        b = _branch(cmd[sl], m[sl], se[sl], neutral_command, p, target)
        branch_of[sl] = len(branches)
        fit[sl] = b.thrust_fit_n
        if b.saturated:
            state[sl][(cmd[sl] >= b.saturated[0]) & (cmd[sl] <= b.saturated[1])] = "saturated"
        branches.append(b)
    start_stop = {} if sweep is None else _start_stop(
        pts, sweep[ok], _live_points(pts, line, speed_mean[ok], p, floor), neutral_command,
        branches)
    return CommandCurve(
        command_unit=command_unit, neutral_command=neutral_command, floor_n=floor, zero=line,
        command=cmd, n_points=k, thrust_mean_n=m, thrust_se_n=se, thrust_min_n=lo,
        thrust_max_n=hi, speed_mean_rpm=spd, current_mean_a=cur, thrust_fit_n=fit, state=state,
        branch=branch_of, branches=branches, dead_zones=ranges(cmd, dead),
        saturated=[b.saturated for b in branches if b.saturated],
        break_aways=sorted(c for b in branches for c in b.break_aways), warnings=notes,
        start_stop=start_stop,
    )


def _start_stop(pts: ZeroPoints, sweep: np.ndarray, live: np.ndarray, neutral: float,
                branches: list[Branch]) -> dict[str, tuple[float, float]]:
    """The start and stop edges (start_stop_edges), each branch's inverse table trimmed to
    the commands beyond its side's start edge."""
    edges = start_stop_edges(pts.command, sweep, live, neutral)
    for b in branches:
        side = "above" if b.command_lo >= neutral else "below"
        if side in edges:
            _trim_to_start(b, edges[side][1], neutral)
    return edges


def _live_points(pts: ZeroPoints, line: ZeroLine | None, speed: np.ndarray, p: CurveParams,
                 floor: float) -> np.ndarray:
    """Per point: the motor turns (speed feedback), or its thrust stands clear of the zero."""
    if speed.size and np.isfinite(speed).all() and np.any(speed != 0):
        return np.abs(speed) > p.speed_floor_frac * float(np.max(np.abs(speed)))
    z = line.at(pts.t_s) if line is not None else np.zeros(pts.t_s.size)
    return np.abs(pts.mean - z) > np.maximum(p.k_se * pts.se, floor)


def start_stop_edges(command: np.ndarray, sweep: np.ndarray, live: np.ndarray,
                     neutral: float) -> dict[str, tuple[float, float]]:
    """Per side of neutral ("above"/"below"), (stop edge, start edge) where they differ: the
    start edge is the command nearest neutral from which every point swept away from neutral
    turns the motor; the stop edge the same for the points swept back towards neutral. Only
    where a point swept away from neutral was dead at or beyond the stop edge: a command the
    motor turns at on the way back but not from rest. (A log that enters a side at its far
    end and sweeps back never tried to start the motor nearer neutral: no edge from it.)"""
    out = {}
    for side, sign in (("above", 1.0), ("below", -1.0)):
        mine = sign * (command - neutral) > 0
        away = mine & (sweep == ("up" if sign > 0 else "down"))
        back = mine & (sweep == ("down" if sign > 0 else "up"))
        start, stop = _edge(command[away], live[away], sign), _edge(command[back], live[back], sign)
        if start is None or stop is None or not sign * (start - stop) > 0:
            continue
        if (away & ~live & (sign * (command - stop) >= 0)).any():
            out[side] = (stop, start)
    return out


def _edge(command: np.ndarray, live: np.ndarray, sign: float) -> float | None:
    """The command nearest neutral beyond the last dead point of one sweep direction (its
    nearest live point when none is dead; None without a live point)."""
    if not live.any():
        return None
    dist = sign * command
    last_dead = float(np.max(dist[~live])) if (~live).any() else -np.inf
    beyond = live & (dist > last_dead)
    return float(sign * np.min(dist[beyond])) if beyond.any() else None


def _trim_to_start(b: Branch, start: float, neutral: float) -> None:
    """Drop from a branch's inverse table the commands between neutral and `start`: from
    rest they do not turn the motor, whatever the way back gave there."""
    keep = np.abs(b.lut_command - neutral) >= abs(start - neutral)
    if keep.any():
        b.lut_thrust_n, b.lut_command = b.lut_thrust_n[keep], b.lut_command[keep]


def _not_turning(speed: np.ndarray, speed_se: np.ndarray | None,
                 p: CurveParams) -> np.ndarray | None:
    """Per point: the propeller does not turn (None without speed feedback on every point)."""
    if not speed.size or not np.isfinite(speed).all() or not np.any(speed != 0):
        return None
    noise = p.k_se * np.nan_to_num(speed_se) if speed_se is not None else 0.0
    return np.abs(speed) <= np.maximum(noise, p.speed_floor_frac * float(np.max(np.abs(speed))))


def _find_zero(pts: ZeroPoints, anchors: Anchors, hint: np.ndarray | None, neutral: float,
               floor: float, p: CurveParams) -> ZeroLine | None:
    """The zero from the joint search, or, with nothing to anchor it (no tare, no neutral
    command, no feedback), iterated from a zero of 0 over the dead points."""
    if hint is None and anchors.empty and not (pts.command == neutral).any():
        return _zero_from_dead_points(pts, floor, p, anchors)
    return search_zero(pts, anchors, neutral, floor, p.k_se, hint)


def _imitated(pts: ZeroPoints, anchors: Anchors, cmd: np.ndarray, dead: np.ndarray,
              floor: float, neutral: float, unit: str, p: CurveParams
              ) -> tuple[np.ndarray, list[str]]:
    """The dead mask with the commands a drift could equally make dead added, and warnings."""
    thr = np.maximum(p.k_se * pts.se, floor)
    found = imitations(pts, anchors, cmd, dead, thr, neutral, p.k_se)
    out = dead.copy()
    for f in found:
        out |= np.isin(cmd, f.commands)
    return out, [_imitation_text(f, cmd, unit) for f in found]


def _imitation_text(f: Imitation, cmd: np.ndarray, unit: str) -> str:
    """The warning for one dead zone whose neighbours a drift could make dead."""
    names = ", ".join(f"{a:g}" if a == b else f"{a:g}-{b:g}"
                      for a, b in ranges(cmd, np.isin(cmd, f.commands)))
    known = (f"they read the zero that the other dead points and the tares give, within its "
             f"uncertainty there (+-{f.band_n:.2g} N)" if math.isfinite(f.band_n) else
             "the other dead points and the tares do not fix the zero's drift there")
    return (f"cannot tell a zero drift from a small thrust at {unit} {names}: beside the dead "
            f"zone {f.zone[0]:g}-{f.zone[1]:g}, {known}; counted as dead, so the inverse table "
            "does not use them (tare during the sweep, sweep up and down, or measure speed to "
            "tell)")


def _zero_from_dead_points(pts: ZeroPoints, floor: float, p: CurveParams,
                           anchors: Anchors = NO_ANCHORS) -> ZeroLine | None:
    """Sensor zero (offset + linear drift in time) read from every dead zone, iterated from 0.

    Each pass finds the dead commands relative to the current zero line, allowing for the
    line's own uncertainty at each point's time, then fits the line through all their points
    (weighted, serially correlated errors, gross outliers such as a zone's live edge dropped).
    Used only when nothing anchors the zero: no tare, no feedback, neutral command not swept
    (`anchors` then holds no tare, only a resumed run's sessions).
    """
    line = None
    previous = None
    for _ in range(ZERO_PASSES):
        z = line.at(pts.t_s) if line else np.zeros(pts.command.size)
        var = line.var_at(pts.t_s) if line else np.zeros(pts.command.size)
        cmd, _k, m, s, _lo, _hi, var_zero = aggregate(pts.command, pts.mean - z, pts.se,
                                                      pts.mean, pts.mean, var)
        s = np.sqrt(s**2 + var_zero)
        dead = find_dead(m, s, floor, p)
        if dead.sum() >= MIN_ZERO_POINTS:
            scatter = p.k_zero * 1.4826 * float(np.median(np.abs(m[dead])))
            dead = find_dead(m, s, max(floor, scatter), p)
        keep = np.isin(pts.command, zone_cores(cmd, dead))
        if not keep.any() or (previous is not None and np.array_equal(keep, previous)):
            break
        previous = keep
        line = fit_zero_line(pts.take(keep), anchors)
    return line


def _live_segments(direction: np.ndarray, dead: np.ndarray) -> list[tuple[int, int]]:
    """Runs of live commands, split where the direction (sign of thrust or speed) changes."""
    out = []
    for start, stop in runs(~dead):
        sign = direction[start:stop]
        cuts = np.flatnonzero(sign[1:] != sign[:-1]) + 1
        bounds = [0, *cuts.tolist(), stop - start]
        out.extend((start + a, start + b) for a, b in zip(bounds[:-1], bounds[1:], strict=True))
    return out


def _branch(cmd: np.ndarray, m: np.ndarray, se: np.ndarray, neutral: float,
            p: CurveParams, law_thrust: np.ndarray | None = None) -> Branch:
    """One branch: the monotone fit of its thrusts (of `law_thrust`, the thrust law at its
    points' speeds, where given and finite), its saturation, break-aways and inverse table."""
    from scipy.optimize import isotonic_regression  # on use; sklearn's costs 1.9 s more to import

    sign = 1 if np.nanmedian(m) > 0 else -1
    away = 1 if np.mean(cmd) >= neutral else -1
    slope = np.polyfit(cmd, m, 1)[0] if cmd.size >= 2 else 0.0
    slope_sign = int(np.sign(slope)) or sign * away
    weights = 1.0 / np.maximum(np.nan_to_num(se, nan=np.inf), 1e-6 * np.max(np.abs(m)) + 1e-12) ** 2
    if law_thrust is not None and np.isfinite(law_thrust).all():
        m_fit, weights = law_thrust, np.ones(cmd.size)
    else:
        m_fit = m
    g = isotonic_regression(m_fit, weights=weights, increasing=slope_sign > 0).x
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
