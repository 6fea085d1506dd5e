"""Short-block means of a run's samples, the common time base of BETM, events and the GP.

Samples within a point are strongly autocorrelated and come at 500-1000 Hz; block means over
0.1-0.2 s keep the dynamics of a ventilation event (onset ramps of ~0.2 s) while cutting the
white sensor noise by sqrt(samples per block) and the data volume by the same factor.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rigtool.analysis.dataset import RunData, Samples, SampleSource


@dataclass
class Blocks:
    """One row per block: times (run clock), means, and the owning point (row of run.steps)."""

    t_s: np.ndarray  # block centre time
    t0_s: np.ndarray  # first sample time of the block
    t1_s: np.ndarray  # last sample time of the block
    thrust_n: np.ndarray
    speed_rpm: np.ndarray
    current_a: np.ndarray
    point: np.ndarray
    depth_m: np.ndarray
    command: np.ndarray
    t_in_point_s: np.ndarray  # block centre minus the point's first sample time
    block_s: float

    def __len__(self) -> int:
        return len(self.t_s)

    def take(self, index: np.ndarray) -> Blocks:
        """Rows `index` as new Blocks."""
        keys = [k for k in self.__dataclass_fields__ if k != "block_s"]
        return Blocks(**{k: getattr(self, k)[index] for k in keys}, block_s=self.block_s)


def block_means(run: RunData, block_s: float = 0.2) -> Blocks:
    """Means over consecutive `block_s` blocks inside each point (a partial last block is
    dropped), read one block of points at a time (a point longer than a block in pieces)."""
    rows: dict[str, list[np.ndarray]] = {k: [] for k in (
        "t_s", "t0_s", "t1_s", "thrust_n", "speed_rpm", "current_a", "point", "t_in_point_s")}
    for chunk in run.source.blocks(_FIELDS):
        if chunk.piece:
            if chunk.start == 0:
                _long_point_blocks(run.source, chunk.first_row, block_s, rows)
            continue
        _point_blocks(chunk.samples, chunk.first_row, block_s, rows)
    cat = {k: (np.concatenate(v) if v else np.empty(0)) for k, v in rows.items()}
    point = cat.pop("point").astype(int)
    return Blocks(**cat, point=point, depth_m=run.steps.depth_m[point],
                  command=run.steps.command[point], block_s=block_s)


_FIELDS = ("t_s", "thrust_n", "speed_rpm", "current_a")


def _block_size(n: int, t_first: float, t_last: float, block_s: float) -> int:
    """Samples per block of a point of `n` samples from `t_first` to `t_last`."""
    rate = (n - 1) / max(t_last - t_first, 1e-12)
    return max(int(round(block_s * rate)), 1)


def _point_blocks(s: Samples, first_row: int, block_s: float,
                  rows: dict[str, list[np.ndarray]]) -> None:
    """Append the block means of the points of `s` (steps rows from `first_row`) to `rows`."""
    off = s.offsets
    for p in range(len(off) - 1):
        a, b = int(off[p]), int(off[p + 1])
        if b - a < 2:
            continue
        size = _block_size(b - a, s.t_s[a], s.t_s[b - 1], block_s)
        end = a + (b - a) // size * size
        if end > a:
            _append(s, a, end, size, first_row + p, s.t_s[a], rows)


def _long_point_blocks(source: SampleSource, row: int, block_s: float,
                       rows: dict[str, list[np.ndarray]]) -> None:
    """`_point_blocks` of one point longer than a block, read in pieces: the samples of a
    block a piece cuts are carried into the next piece, so every block is the same."""
    n = int(source.point_counts()[row])
    times = [(p.samples.t_s[0], p.samples.t_s[-1]) for p in source.pieces(row, ("t_s",))]
    if n < 2 or not times:
        return
    size = _block_size(n, times[0][0], times[-1][1], block_s)
    left = n // size * size  # samples in whole blocks
    carry: dict[str, np.ndarray] = {k: np.empty(0) for k in _FIELDS}
    for piece in source.pieces(row, _FIELDS):
        s = piece.samples
        cols = {k: np.concatenate((carry[k], getattr(s, k))) for k in _FIELDS}
        take = min(cols["t_s"].size // size * size, left)
        if take:
            whole = Samples(**{k: v[:take] for k, v in cols.items()}, point=np.empty(0, int),
                            offsets=np.empty(0, int))
            _append(whole, 0, take, size, row, times[0][0], rows)
        left -= take
        carry = {k: v[take:] for k, v in cols.items()}


def _append(s: Samples, a: int, end: int, size: int, row: int, t_first: float,
            rows: dict[str, list[np.ndarray]]) -> None:
    """Append the means of blocks of `size` samples of `s`, samples a .. end - 1 (whole
    blocks of steps row `row`, whose first sample is at `t_first`), to `rows`."""
    def mean(x: np.ndarray) -> np.ndarray:
        return np.nanmean(x[a:end].reshape(-1, size), axis=1)

    tb = s.t_s[a:end].reshape(-1, size)
    rows["t_s"].append(tb.mean(axis=1))
    rows["t0_s"].append(tb[:, 0])
    rows["t1_s"].append(tb[:, -1])
    rows["thrust_n"].append(mean(s.thrust_n))
    rows["speed_rpm"].append(mean(s.speed_rpm))
    rows["current_a"].append(mean(s.current_a))
    rows["point"].append(np.full(tb.shape[0], row))
    rows["t_in_point_s"].append(tb.mean(axis=1) - t_first)


def in_intervals(t: np.ndarray, intervals: list[tuple[float, float]]) -> np.ndarray:
    """Mask of times inside any [a, b] interval."""
    m = np.zeros(t.size, bool)
    for a, b in intervals:
        m |= (t >= a) & (t <= b)
    return m


def windows_of(blocks: Blocks) -> list[tuple[float, float]]:
    """Acquisition window (first to last sample time) of every point."""
    return [(float(blocks.t0_s[blocks.point == p].min()), float(blocks.t1_s[blocks.point == p].max()))
            for p in np.unique(blocks.point)]


def classify(blocks: Blocks, events: list[tuple[float, float]], edge_s: float) -> np.ndarray:
    """Class per block: 'step' (within edge_s of a point start), 'edge' (of an event start or
    end inside the window), 'event', 'outside'."""
    cls = np.full(len(blocks), "outside", dtype=object)
    ev = in_intervals(blocks.t_s, events)
    cls[ev] = "event"
    wins = windows_of(blocks)
    edges = [x for a, b in events for x in (a, b) if any(wa < x < wb for wa, wb in wins)]
    near = np.zeros(len(blocks), bool)
    for x in edges:
        near |= np.abs(blocks.t_s - x) <= edge_s
    cls[near] = "edge"
    cls[blocks.t_in_point_s <= edge_s] = "step"
    return cls
