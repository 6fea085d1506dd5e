"""The sensor zero and the dead commands, found jointly (used by curves.py without a given zero).

The thrust zero left after taring is a line in time, z(t) = a + d (t - t0). A dead command reads
z at each of its points' times; a live one reads its thrust on top. The tare before the points
fixes z = 0 at its time (an anchor) and a drift known from three or more tares bounds d; without
a tare, the neutral command (where the driver stops the motor, and where a tare would be taken)
anchors the line. With speed feedback, the points where the motor does not turn are the dead ones.

Search: every point proposes the drift that would put it on a line through the anchor; the drift
whose line the most commands read as zero (every visit of a command must agree, so a command
swept twice must read the zero at both times) wins, and is refined by weighted least squares
over the cores of the dead zones and the anchor, reclassifying until the dead set is stable.
The zone at the neutral command, with the anchor, then gives a drift a creep cannot fake; a
second search within k_se standard errors of it settles the other zones, so a flat creep far in
time from the tare cannot outvote it. Where the other zones and the tare fix the zero too
loosely to tell a zone from the small thrust beside it, `imitations` names those commands.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rigtool.analysis.fits import (
    LinearFit,
    ZeroLine,
    occupied_starts,
    session_columns,
    session_index,
    session_line,
    wls,
)

ZERO_PASSES = 6
MIN_ZONE = 3  # a dead set without a run this long (or the neutral command) is a chance crossing
OUTLIER_K = 5.0  # zero-line points further than this many robust SDs from the line are dropped
DRIFT_K = 3.0  # a zero drift is kept when it exceeds this many standard errors
ANCHOR_SE_FACTOR = 2.0  # a tare's SE, in dead points' SEs (it averages fewer readings)
MAX_CANDIDATES = 2000  # drifts tried by the consensus search (points beyond are subsampled)
ISOLATED = 3.0  # as CurveParams.isolated_factor: a marginal live command inside a zone is dead
STEP_DRIFT = 2.0  # the search's drifts move the zero by at most this many floors per point


@dataclass(frozen=True)
class ZeroPoints:
    """Per-point inputs of the zero search: command, time (s), mean and SE of thrust (N)."""

    command: np.ndarray
    t_s: np.ndarray
    mean: np.ndarray
    se: np.ndarray

    def take(self, keep: np.ndarray) -> ZeroPoints:
        """The points selected by a boolean mask."""
        return ZeroPoints(self.command[keep], self.t_s[keep], self.mean[keep], self.se[keep])


@dataclass(frozen=True)
class Anchors:
    """Where the zero is known: 0 at the tare times `t_s`, and drift (N/s, SE) from the tares;
    `sessions` are the start times of a resumed run's later sessions (each re-zeroed: its own
    offset, one drift for all). `drifts`: False where the sweep's design cannot separate a
    drift from the thrust (drift_design.py): every line is then flat."""

    t_s: np.ndarray
    drift: tuple[float, float] | None = None
    sessions: tuple[float, ...] = ()
    drifts: bool = True

    @property
    def empty(self) -> bool:
        """True without a tare and without a tare drift."""
        return self.t_s.size == 0 and self.drift is None


NO_ANCHORS = Anchors(np.zeros(0))


def section_anchors(tare_t_s: np.ndarray | None, t_s: np.ndarray,
                    tare_drift: tuple[float, float] | None = None,
                    sessions: tuple[float, ...] = ()) -> Anchors:
    """The tare that zeroes these points: the last one before the first point, when no tare
    re-zeroes the sensor during them (then the zero of the points is a sawtooth, not a line,
    and nearly flat when every point is tared: no anchor). The tares' drift goes with it.
    A resumed run (`sessions`) is taken session by session: each may have its own tare."""
    if tare_t_s is None or not np.isfinite(t_s).any():
        return Anchors(np.zeros(0), None, sessions) if sessions else NO_ANCHORS
    tares = np.sort(np.asarray(tare_t_s, dtype=float)[np.isfinite(tare_t_s)])
    if sessions:
        t = np.asarray(t_s, dtype=float)
        point_session, tare_session = session_index(t, sessions), session_index(tares, sessions)
        found = [_anchor(tares[tare_session == k], t[point_session == k])
                 for k in np.unique(point_session[np.isfinite(t)])]
        found = [a for a in found if a is not None]
        return Anchors(np.array(found, dtype=float), tare_drift if found else None, sessions)
    anchor = _anchor(tares, t_s)
    return NO_ANCHORS if anchor is None else Anchors(np.array([anchor]), tare_drift)


def _anchor(tares: np.ndarray, t_s: np.ndarray) -> float | None:
    """The last of the sorted `tares` before the first of the times `t_s`, when none falls
    between their first and last (None otherwise)."""
    if not np.isfinite(t_s).any():
        return None
    first, last = float(np.nanmin(t_s)), float(np.nanmax(t_s))
    before = tares[tares <= first]
    if not before.size or ((tares > first) & (tares <= last)).any():
        return None
    return float(before[-1])


@dataclass(frozen=True)
class _Search:
    """What every step of the search needs: the points, anchors, neutral command, dead
    threshold per point, k_se, and the (time, zero) the candidate lines pass through: one per
    session (`bounds`: the start times of the later sessions that hold points)."""

    pts: ZeroPoints
    anchors: Anchors
    neutral: float
    thr: np.ndarray
    k_se: float
    start: tuple[tuple[float, float], ...]
    bounds: tuple[float, ...] = ()

    def through(self) -> tuple[np.ndarray, np.ndarray]:
        """Per point, the (time, zero) its session's candidate lines pass through."""
        if not self.bounds:
            t0, z0 = self.start[0]
            return np.full(self.pts.t_s.size, t0), np.full(self.pts.t_s.size, z0)
        k = session_index(self.pts.t_s, self.bounds)
        t0, z0 = np.array(self.start, dtype=float).T
        return t0[k], z0[k]

    def line(self, drift: float) -> ZeroLine:
        """The line with `drift` through every session's start."""
        t0, z0 = self.start[0]
        if not self.bounds:
            return ZeroLine(z0, drift, t0, "dead zones")
        offsets = np.array([z + drift * (t0 - t) for t, z in self.start])
        return session_line(offsets, drift, t0, "dead zones", None, self.bounds)


def search_zero(pts: ZeroPoints, anchors: Anchors, neutral: float, floor: float,
                k_se: float, dead_hint: np.ndarray | None = None) -> ZeroLine | None:
    """The zero line and dead set found jointly (None: no dead point and no anchor to fix it).

    A first search over every drift the points allow finds the zone at the neutral command;
    the drift that zone and the anchors give (within k_se SEs) bounds a second search, so a
    larger flat run far away (a creep of nearly constant thrust) cannot outvote them.
    `dead_hint` (per point) marks points known dead from feedback (the motor does not turn):
    then the line is fitted through them and the anchors, nothing is searched (None if the
    motor turns at every point).
    """
    if dead_hint is not None:
        return fit_zero_line(pts.take(dead_hint), anchors) if dead_hint.any() else None
    bounds = occupied_starts(pts.t_s, anchors.sessions)
    start = _anchor_points(pts, anchors, neutral, bounds)
    if start is None:
        return None
    search = _Search(pts, anchors, neutral, np.maximum(k_se * pts.se, floor), k_se, start,
                     bounds)
    limit = _max_drift(pts.t_s, floor) if anchors.drifts else 0.0
    line = _settle(search, _consensus_drift(search, (-limit, limit)))
    window = _neutral_window(search, line)
    return line if window is None else _settle(search, _consensus_drift(search, window))


def _settle(s: _Search, drift: float) -> ZeroLine | None:
    """From the line through the start with `drift`: dead set, then the line fitted through
    its zones' cores and the anchors, again until the dead set stops changing (None when the
    dead set is only a chance crossing of the curve)."""
    line: ZeroLine | None = s.line(drift)
    previous = None
    for _ in range(ZERO_PASSES):
        cmd, dead = dead_commands(s.pts, line, s.thr)
        if previous is not None and np.array_equal(dead, previous):
            break
        previous = dead
        if not _plausible(cmd, dead, s.neutral):
            return None
        line = fit_zero_line(s.pts.take(np.isin(s.pts.command, zone_cores(cmd, dead))),
                             s.anchors)
        if line is None:
            break
    return line


def _neutral_window(s: _Search, line: ZeroLine | None) -> tuple[float, float] | None:
    """Drifts (N/s) within k_se SEs of the one the neutral command's zone and the anchors
    give on their own (None without such a zone or without a drift from it)."""
    if line is None:
        return None
    cmd, dead = dead_commands(s.pts, line, s.thr)
    zone = next(((a, b) for a, b in runs(dead) if cmd[a] <= s.neutral <= cmd[b - 1]), None)
    if zone is None:
        return None
    own = np.zeros(cmd.size, dtype=bool)
    own[zone[0]:zone[1]] = True
    fit = fit_zero_line(s.pts.take(np.isin(s.pts.command, zone_cores(cmd, own))), s.anchors,
                        force_drift=True)
    if fit is None or fit.cov is None or fit.cov[1][1] <= 0:
        return None
    half = s.k_se * math.sqrt(fit.cov[1][1])
    return fit.drift_n_per_s - half, fit.drift_n_per_s + half


def _anchor_points(pts: ZeroPoints, anchors: Anchors, neutral: float,
                   bounds: tuple[float, ...]) -> tuple[tuple[float, float], ...] | None:
    """Per session (`bounds`: the later ones' start times), the (time, zero) the search's
    lines pass through: its first tare, else its first visit of the neutral command, else
    (a later session with neither) the previous session's; None when the first has neither."""
    out: list[tuple[float, float]] = []
    tare_session = session_index(anchors.t_s, bounds)
    point_session = session_index(pts.t_s, bounds)
    for k in range(len(bounds) + 1):
        here = _anchor_point(pts.take(point_session == k), anchors.t_s[tare_session == k],
                             neutral)
        if here is None and not out:
            return None
        out.append(here if here is not None else out[-1])
    return tuple(out)


def _anchor_point(pts: ZeroPoints, tares: np.ndarray,
                  neutral: float) -> tuple[float, float] | None:
    """(time, zero) the search's lines pass through: the first tare, else the first visit of
    the neutral command."""
    if tares.size:
        return float(tares[0]), 0.0
    at = np.flatnonzero(pts.command == neutral)
    if not at.size:
        return None
    first = at[np.argmin(pts.t_s[at])]
    return float(pts.t_s[first]), float(pts.mean[first])


def _max_drift(t_s: np.ndarray, floor: float) -> float:
    """The fastest drift (N/s) searched: one that moves the zero by STEP_DRIFT floors between
    neighbouring points (faster, a dead zone would look like a ramp, and a ramp like a zone)."""
    steps = np.diff(np.unique(t_s))
    return STEP_DRIFT * floor / float(np.median(steps)) if steps.size else 0.0


def _consensus_drift(s: _Search, window: tuple[float, float]) -> float:
    """The drift (N/s) in `window` of the line through the start that the most commands read
    as zero (every point of a command counts, each command as one)."""
    t0, z0 = s.through()
    dt = s.pts.t_s - t0
    usable = np.flatnonzero(np.abs(dt) > 0)
    proposed = (s.pts.mean[usable] - z0[usable]) / dt[usable]
    proposed = proposed[(proposed >= window[0]) & (proposed <= window[1])]
    if proposed.size > MAX_CANDIDATES:
        proposed = np.sort(proposed)[np.linspace(0, proposed.size - 1, MAX_CANDIDATES).astype(int)]
    candidates = np.concatenate([[float(np.clip(0.0, *window)), sum(window) / 2], proposed])
    if s.anchors.drift is not None:
        candidates = np.append(candidates, s.anchors.drift[0])
    _, inv = np.unique(s.pts.command, return_inverse=True)
    weight = 1.0 / np.bincount(inv)[inv]
    cost = np.empty(candidates.size)
    for lo in range(0, candidates.size, 256):
        d = candidates[lo:lo + 256, None]
        r = (s.pts.mean[None, :] - z0[None, :] - d * dt[None, :]) / s.thr[None, :]
        cost[lo:lo + 256] = np.minimum(r * r, 1.0) @ weight
    if s.anchors.drift is not None:  # a drift k_se SEs off the tares' costs every command
        value, se = s.anchors.drift
        cost += weight.sum() * ((candidates - value) / (s.k_se * max(se, 1e-12))) ** 2
    return float(candidates[np.argmin(cost)])


def dead_commands(pts: ZeroPoints, line: ZeroLine, thr: np.ndarray) -> tuple[np.ndarray,
                                                                             np.ndarray]:
    """(sorted commands, dead mask): a command is dead when every point of it reads the zero;
    a live one between two dead ones is dead too if no point is off by ISOLATED thresholds."""
    cmd, inv = np.unique(pts.command, return_inverse=True)
    ratio = np.abs(pts.mean - line.at(pts.t_s)) / thr
    worst = np.zeros(cmd.size)
    np.maximum.at(worst, inv, ratio)
    dead = worst <= 1.0
    inner = np.arange(1, cmd.size - 1)
    isolated = ~dead[inner] & dead[inner - 1] & dead[inner + 1] & (worst[inner] < ISOLATED)
    dead[inner[isolated]] = True
    return cmd, dead


def _plausible(cmd: np.ndarray, dead: np.ndarray, neutral: float) -> bool:
    """A dead set that is more than a chance crossing of the curve: it holds the neutral
    command or a run of MIN_ZONE commands."""
    if dead[cmd == neutral].any():
        return True
    return any(stop - start >= MIN_ZONE for start, stop in runs(dead))


def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Contiguous runs of True in `mask` as (start, stop) index pairs."""
    padded = np.concatenate(([False], mask, [False])).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def zone_cores(cmd: np.ndarray, dead: np.ndarray) -> np.ndarray:
    """Dead commands away from their zone's edges, where live thrust can leak into the zone.

    A zone of four or more commands loses a quarter of its length at each end that borders a
    live command; shorter zones are kept whole.
    """
    keep = []
    for start, stop in runs(dead):
        size = stop - start
        cut = size // 4 if size >= 4 else 0
        lo = start + (cut if start > 0 else 0)
        hi = stop - (cut if stop < cmd.size else 0)
        keep.append(cmd[lo:hi])
    return np.concatenate(keep) if keep else np.zeros(0)


def fit_zero_line(pts: ZeroPoints, anchors: Anchors, force_drift: bool = False
                  ) -> ZeroLine | None:
    """Offset, plus a drift when it is significant (or `force_drift`), through the points and
    the anchors (0 at the tare time, the tares' drift as a constraint on the slope); an offset
    per session of `anchors.sessions` that holds any of them, one drift for all."""
    t, y, se = _with_anchors(pts, anchors)
    if t.size == 0:
        return None
    force_drift = force_drift and anchors.drifts
    starts = occupied_starts(t, anchors.sessions)
    if starts:
        return _session_zero_line(t, y, se, anchors, starts, force_drift)
    t_ref = float(np.mean(t))
    flat = _robust_wls(np.ones((t.size, 1)), y, se, t)
    design, y2, se2, t2 = _sloped_design(t, y, se, t_ref, anchors)
    if anchors.drifts and ((design.shape[0] >= 3 and np.ptp(t) > 0)
                           or anchors.drift is not None):
        sloped = _robust_wls(design, y2, se2, t2)
        c = sloped.cov
        if force_drift or abs(sloped.beta[1]) > DRIFT_K * math.sqrt(max(c[1, 1], 0.0)):
            return ZeroLine(float(sloped.beta[0]), float(sloped.beta[1]), t_ref, "dead zones",
                            ((float(c[0, 0]), float(c[0, 1])), (float(c[1, 0]), float(c[1, 1]))))
    return ZeroLine(float(flat.beta[0]), 0.0, t_ref, "dead zones",
                    ((float(flat.cov[0, 0]), 0.0), (0.0, 0.0)))


def _session_zero_line(t: np.ndarray, y: np.ndarray, se: np.ndarray, anchors: Anchors,
                       starts: tuple[float, ...], force_drift: bool) -> ZeroLine:
    """`fit_zero_line` for points (and anchors) in several sessions: one offset each."""
    t_ref = float(np.mean(t))
    offsets = np.column_stack(session_columns(t, starts))
    m = offsets.shape[1]
    flat = _robust_wls(offsets, y, se, t)
    design = np.column_stack([offsets, t - t_ref])
    y2, se2, t2 = y, se, t
    if anchors.drift is not None:
        value, sd = anchors.drift
        row = np.zeros((1, m + 1))
        row[0, -1] = 1.0
        design, y2, se2, t2 = (np.vstack([design, row]), np.append(y, value), np.append(se, sd),
                               np.append(t, t_ref))
    if (design.shape[0] >= m + 2 and np.ptp(t) > 0) or anchors.drift is not None:
        sloped = _robust_wls(design, y2, se2, t2)
        c = sloped.cov
        if force_drift or abs(sloped.beta[-1]) > DRIFT_K * math.sqrt(max(c[-1, -1], 0.0)):
            return session_line(sloped.beta[:-1], float(sloped.beta[-1]), t_ref, "dead zones",
                                np.array(c, dtype=float), starts)
    cov = np.zeros((m + 1, m + 1))
    cov[:m, :m] = flat.cov
    return session_line(flat.beta, 0.0, t_ref, "dead zones", cov, starts)


def _with_anchors(pts: ZeroPoints, anchors: Anchors) -> tuple[np.ndarray, ...]:
    """Times, values and SEs of the points with a zero reading at the tare appended."""
    n = anchors.t_s.size
    if not n:
        return pts.t_s, pts.mean, pts.se
    se_anchor = ANCHOR_SE_FACTOR * (float(np.median(pts.se)) if pts.se.size else 0.0)
    se_anchor = se_anchor or 1e-4
    return (np.concatenate([anchors.t_s, pts.t_s]), np.concatenate([np.zeros(n), pts.mean]),
            np.concatenate([np.full(n, se_anchor), pts.se]))


def _sloped_design(t: np.ndarray, y: np.ndarray, se: np.ndarray, t_ref: float,
                   anchors: Anchors) -> tuple[np.ndarray, ...]:
    """Design [1, t - t_ref] for offset and drift, plus a row for the tare drift if known."""
    design = np.column_stack([np.ones(t.size), t - t_ref])
    if anchors.drift is None:
        return design, y, se, t
    value, sd = anchors.drift
    return (np.vstack([design, [0.0, 1.0]]), np.append(y, value), np.append(se, sd),
            np.append(t, t_ref))


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


@dataclass(frozen=True)
class Imitation:
    """Live commands beside a dead zone that a zero as consistent with the other dead points
    and the tares would call dead (and the zone live): the data cannot tell a drift from a
    small thrust there."""

    zone: tuple[float, float]
    commands: np.ndarray
    band_n: float  # largest uncertainty (k_se SE) of that zero at those commands


def imitations(pts: ZeroPoints, anchors: Anchors, cmd: np.ndarray, dead: np.ndarray,
               thr: np.ndarray, neutral: float, k_se: float) -> list[Imitation]:
    """For each dead zone without the neutral command: the zero predicted from everything else
    (other zones' cores, tares; no drift known if they cannot fix one), and the live commands
    next to it that read that zero within its uncertainty at every visit."""
    out = []
    for start, stop in runs(dead):
        if cmd[start] <= neutral <= cmd[stop - 1]:
            continue
        others = dead.copy()
        others[start:stop] = False
        rest = _rest_line(pts.take(np.isin(pts.command, zone_cores(cmd, others))), anchors)
        band = _band(rest, pts.t_s, k_se)
        found = _beside(pts, rest, band, cmd, dead, (start, stop), thr)
        if found:
            out.append(Imitation((float(cmd[start]), float(cmd[stop - 1])), np.array(sorted(found)),
                                 float(np.max(band[np.isin(pts.command, found)]))))
    return out


def _rest_line(pts: ZeroPoints, anchors: Anchors) -> ZeroLine:
    """The zero line through the other dead points and the tares (0 without any)."""
    line = fit_zero_line(pts, anchors, force_drift=True)
    return line if line is not None else ZeroLine(0.0, 0.0, 0.0, "none")


def _band(rest: ZeroLine, t_s: np.ndarray, k_se: float) -> np.ndarray:
    """k_se standard errors of `rest` at each time; infinite where it fixes no drift."""
    if rest.cov is None or rest.cov[1][1] <= 0:
        return np.full(t_s.size, np.inf)
    return k_se * np.sqrt(rest.var_at(t_s))


def _beside(pts: ZeroPoints, rest: ZeroLine, band: np.ndarray, cmd: np.ndarray,
            dead: np.ndarray, zone: tuple[int, int], thr: np.ndarray) -> list[float]:
    """Live commands walking out from both ends of `zone` that read the `rest` zero within its
    uncertainty `band`, and one zero together (what a dead zone there would read)."""
    off = pts.mean - rest.at(pts.t_s)
    fits = np.abs(off) <= thr + band
    found = []
    for step, first in ((-1, zone[0] - 1), (1, zone[1])):
        level = None
        j = first
        while 0 <= j < cmd.size and not dead[j]:
            at = pts.command == cmd[j]
            here = float(np.mean(off[at]))
            if not fits[at].all() or (level is not None
                                      and abs(here - level) > 2 * float(np.max(thr[at]))):
                break
            level = here if level is None else level
            found.append(float(cmd[j]))
            j += step
    return found
