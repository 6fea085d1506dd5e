"""Ventilation event detection: thrust drop against the BETM estimate, with hysteresis.

Within each segment (one point's acquisition), an event starts where the relative drop
r = 1 - f_measured / f_BETM exceeds `on_drop` and lasts until r falls below `off_drop`
(hysteresis: noise near one threshold cannot chatter). Events shorter than `min_duration_s`
are discarded; gaps shorter than `min_gap_s` between two events are bridged. The current
deficit 1 - I / (C_n |n|^3 + I_0) during the event is recorded as supporting evidence (the
driver current drops slightly when the propeller draws air), not used to gate detection.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np


@dataclass(frozen=True)
class EventParams:
    """Detection thresholds (recorded with the results)."""

    on_drop: float = 0.12  # relative thrust drop that starts an event
    off_drop: float = 0.06  # relative drop below which it ends
    min_duration_s: float = 0.3
    min_gap_s: float = 0.2
    min_thrust_n: float = 2.0  # |f_BETM| below this: no drop is computed

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class Event:
    """One detected ventilation event (times on the run clock)."""

    t_start_s: float
    t_end_s: float
    segment: int
    mean_drop: float
    peak_drop: float
    current_deficit: float
    current_supports: bool
    open_start: bool  # already under way when the segment began
    open_end: bool  # still under way when the segment ended

    @property
    def duration_s(self) -> float:
        return self.t_end_s - self.t_start_s


def relative_drop(f_meas: np.ndarray, f_ref: np.ndarray, min_thrust_n: float) -> np.ndarray:
    """1 - f_meas / f_ref, NaN where |f_ref| < min_thrust_n."""
    f_ref = np.asarray(f_ref, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(np.abs(f_ref) >= min_thrust_n, 1.0 - np.asarray(f_meas) / f_ref, np.nan)


def detect_events(t_s: np.ndarray, drop: np.ndarray, segment: np.ndarray,
                  params: EventParams | None = None,
                  current_deficit: np.ndarray | None = None) -> list[Event]:
    """Events in a series of relative drops (time-ordered within each segment)."""
    p = params or EventParams()
    t = np.asarray(t_s, dtype=float)
    r = np.asarray(drop, dtype=float)
    seg = np.asarray(segment)
    cd = np.full(t.size, np.nan) if current_deficit is None else np.asarray(current_deficit)
    dt = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    events: list[Event] = []
    for s in np.unique(seg):
        idx = np.flatnonzero(seg == s)
        for a, b in _runs(r[idx], p.on_drop, p.off_drop, p.min_gap_s, t[idx]):
            ta, tb = t[idx[a]] - dt / 2, t[idx[b - 1]] + dt / 2
            if tb - ta < p.min_duration_s:
                continue
            inside = idx[a:b]
            outside = np.setdiff1d(idx, inside)
            mine = np.nanmean(cd[inside]) if np.isfinite(cd[inside]).any() else np.nan
            events.append(Event(
                float(ta), float(tb), int(s), float(np.nanmean(r[inside])),
                float(np.nanmax(r[inside])), float(mine),
                _supports(cd[inside], cd[outside]), a == 0, b == idx.size))
    return events


def _runs(r: np.ndarray, on: float, off: float, min_gap_s: float,
          t: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) index ranges of hysteresis runs, short gaps bridged."""
    out: list[tuple[int, int]] = []
    active, start = False, 0
    for i, v in enumerate(r):
        if not active and v > on:
            active, start = True, i
        elif active and not v >= off:  # NaN ends an event too
            out.append((start, i))
            active = False
    if active:
        out.append((start, r.size))
    merged: list[tuple[int, int]] = []
    for a, b in out:
        if merged and t[a] - t[merged[-1][1] - 1] <= min_gap_s + 1e-9:
            merged[-1] = (merged[-1][0], b)
        else:
            merged.append((a, b))
    return merged


def _supports(inside: np.ndarray, outside: np.ndarray) -> bool:
    """True when the current deficit inside is larger than outside by > 2 standard errors."""
    i, o = inside[np.isfinite(inside)], outside[np.isfinite(outside)]
    if i.size < 2 or o.size < 2:
        return bool(i.size and np.mean(i) > 0)
    se = np.sqrt(np.var(i, ddof=1) / i.size + np.var(o, ddof=1) / o.size)
    return bool(np.mean(i) - np.mean(o) > 2 * se)


@dataclass
class MatchResult:
    """Detected vs true events matched by any time overlap."""

    n_true: int
    n_true_found: int
    n_detected: int
    n_false: int
    n_true_short: int  # true events shorter than the minimum duration (reported apart)
    n_true_short_found: int

    @property
    def recall(self) -> float:
        return self.n_true_found / self.n_true if self.n_true else float("nan")

    @property
    def false_rate(self) -> float:
        return self.n_false / self.n_detected if self.n_detected else 0.0


def match_events(detected: list[tuple[float, float]], truth: list[tuple[float, float]],
                 min_duration_s: float) -> MatchResult:
    """Overlap matching; truth intervals must already be clipped to the observed windows."""
    def overlaps(a: tuple[float, float], b: tuple[float, float]) -> bool:
        return a[0] < b[1] and b[0] < a[1]

    found = [any(overlaps(t, d) for d in detected) for t in truth]
    short = [t[1] - t[0] < min_duration_s for t in truth]
    false = sum(not any(overlaps(d, t) for t in truth) for d in detected)
    n_long = sum(not s for s in short)
    return MatchResult(n_long, sum(f for f, s in zip(found, short, strict=True) if not s),
                       len(detected), false, sum(short),
                       sum(f for f, s in zip(found, short, strict=True) if s))


def clip_to_windows(intervals: list[tuple[float, float]],
                    windows: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """Parts of `intervals` that fall inside the acquisition `windows` (one piece per window)."""
    out = []
    for a, b in intervals:
        for wa, wb in windows:
            lo, hi = max(a, wa), min(b, wb)
            if hi > lo:
                out.append((lo, hi))
    return out
