"""Whether a sweep's design lets a zero drift be told apart from the thrust law.

A linear drift of the sensor zero, z(t) = a + d t, can only be estimated where the same
thrust is read at times far apart: the zero itself (returns to neutral, where the propeller
stands still, and tares), or a command measured again later (an up-down sweep, repeats).
In a one-way sweep time and command move together (time and n^2 correlate at 99 % or more),
so a drift fitted there absorbs whatever the law misses and moves every measured thrust by
it. Then the zero is a constant read from the neutral rows, and no drift is removed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rigtool.analysis.fits import ZeroLine

SEPARATION = 0.25  # readings of one thrust must lie this fraction of the points' span apart
MIN_REPEATED = 2  # commands measured again that far apart, for a drift from repeats


@dataclass(frozen=True)
class DriftDesign:
    """Whether a drift is estimable, and the reason in words (for the warning)."""

    estimable: bool
    reason: str


def drift_design(t_s: np.ndarray, command: np.ndarray, reads_zero: np.ndarray,
                 tare_t_s: np.ndarray) -> DriftDesign:
    """Judge the design of one section's points (`t_s`, `command` of the usable points).

    `reads_zero` marks the points that read the sensor zero (propeller stopped, or the neutral
    command without speed feedback); `tare_t_s` are the tares that zero these points (before
    them or during them; a resumed run's tare at each resume is one).
    """
    t = np.asarray(t_s, dtype=float)
    keep = np.isfinite(t)
    t, command, reads_zero = t[keep], np.asarray(command)[keep], np.asarray(reads_zero)[keep]
    span = float(np.ptp(t)) if t.size else 0.0
    if not span > 0:
        return DriftDesign(False, "the points were read at one time")
    need = SEPARATION * span
    tares = np.asarray(tare_t_s, dtype=float)
    tares = tares[np.isfinite(tares) & (tares <= t.max())]
    visits = _zero_visits(t, reads_zero, tares)
    if visits.size >= 2 and np.ptp(visits) >= need:
        what = ("returns to neutral and tares" if tares.size and reads_zero.any() else
                "tares" if tares.size else "returns to neutral")
        return DriftDesign(True, f"{what} read the zero {np.ptp(visits):.0f} s apart, over a "
                           f"sweep of {span:.0f} s")
    repeated = repeated_apart(t, command, reads_zero)
    if repeated >= MIN_REPEATED:
        return DriftDesign(True, f"{repeated} commands were measured again at least "
                           f"{need:.0f} s later")
    return DriftDesign(False, "one pass with no return to neutral, no re-tare and no command "
                       "measured again later, so time moves with the command and a drift "
                       "cannot be told from the thrust law")


def repeated_apart(t_s: np.ndarray, command: np.ndarray, reads_zero: np.ndarray) -> int:
    """How many commands not reading the zero were measured again at least SEPARATION of
    the points' time span later."""
    t = np.asarray(t_s, dtype=float)
    keep = np.isfinite(t)
    t, command, live = t[keep], np.asarray(command)[keep], ~np.asarray(reads_zero)[keep]
    values, inverse = np.unique(command[live], return_inverse=True)
    if not values.size:
        return 0
    first = np.full(values.size, np.inf)
    last = np.full(values.size, -np.inf)
    np.minimum.at(first, inverse, t[live])
    np.maximum.at(last, inverse, t[live])
    return int(np.sum(last - first >= SEPARATION * float(np.ptp(t))))


def zero_read_apart(t_s: np.ndarray, reads_zero: np.ndarray) -> bool:
    """Whether the points marked `reads_zero` read the zero on separate visits at least
    SEPARATION of the points' time span apart (the returns-to-neutral rule, no tares)."""
    t = np.asarray(t_s, dtype=float)
    keep = np.isfinite(t)
    t, reads_zero = t[keep], np.asarray(reads_zero)[keep]
    span = float(np.ptp(t)) if t.size else 0.0
    visits = _zero_visits(t, reads_zero, np.zeros(0))
    return span > 0 and visits.size >= 2 and float(np.ptp(visits)) >= SEPARATION * span


def _zero_visits(t_s: np.ndarray, reads_zero: np.ndarray, tares: np.ndarray) -> np.ndarray:
    """Mean time of each visit to the zero: a run of consecutive zero-reading points (in time
    order, live points between them end a visit), and each tare. One long run is one visit: a
    zero that seems read all along a one-way sweep is the dead zone found through a drift."""
    order = np.argsort(t_s, kind="stable")
    z = reads_zero[order].astype(np.int8)
    edges = np.flatnonzero(np.diff(np.concatenate(([0], z, [0]))))
    t = t_s[order]
    means = [float(np.mean(t[a:b])) for a, b in zip(edges[::2], edges[1::2], strict=True)]
    return np.sort(np.concatenate([np.array(means), tares]))


def reads_zero(command: np.ndarray, speed_rpm: np.ndarray, neutral_command: float,
               stopped_frac: float) -> np.ndarray:
    """Points that read the sensor zero: the propeller stopped (slower than `stopped_frac` of
    the fastest point) where speed is measured, else the neutral command."""
    n = np.abs(np.asarray(speed_rpm, dtype=float))
    if np.isfinite(n).any() and np.nanmax(n) > 0:
        return np.isfinite(n) & (n <= stopped_frac * float(np.nanmax(n)))
    return np.asarray(command) == neutral_command


def row_noise(t_s: np.ndarray, command: np.ndarray, thrust_n: np.ndarray) -> float:
    """The scatter of one row's thrust about a smooth curve (N): robust SD of the second
    differences, less their median (a curve's own curvature), over sqrt(6). In time order (a
    linear drift drops out of second differences; a sweep up and down stays smooth), or in
    command order for a table without a time axis."""
    ok = np.isfinite(command) & np.isfinite(thrust_n) & np.isfinite(t_s)
    key = t_s[ok] if ok.any() and np.ptp(t_s[ok]) > 0 else command[ok]
    f = thrust_n[ok][np.argsort(key, kind="stable")]
    if f.size < 5:
        return 0.0
    d2 = np.diff(f, 2)
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / math.sqrt(6.0))


def neutral_zero(t_s: np.ndarray, thrust_n: np.ndarray, se_n: np.ndarray,
                 noise_n: float = 0.0) -> ZeroLine | None:
    """The constant zero the neutral rows read (their mean, with its standard error: the
    larger of their scatter's and of `noise_n` (one row's noise) over the root of their
    count, or their own error); None without a row."""
    ok = np.isfinite(thrust_n) & np.isfinite(t_s)
    if not ok.any():
        return None
    f = thrust_n[ok]
    own = float(np.nan_to_num(np.mean(se_n[ok] ** 2))) if np.isfinite(se_n[ok]).any() else 0.0
    scatter = float(np.var(f, ddof=1)) / f.size if f.size >= 2 else 0.0
    var = max(scatter, noise_n**2 / f.size, own / f.size)
    return ZeroLine(float(np.mean(f)), 0.0, float(np.mean(t_s[ok])),
                    "neutral rows", ((var, 0.0), (0.0, 0.0)))
