"""GP training set: block means -> bounded, stratified, weighted (x, y) for the QCTM-GP.

x = (n_p r/min, I A, h m) as measured, GP inputs xf = (n, z, h) (rigtool.models.gp_features:
z is the current-implied thrust loss, N), y = f_measured - f_BETM (N). Strategy: raw samples are averaged
over short blocks (autocorrelated samples carry little extra information), each block gets a
Huber weight from its residual against a running median of y in its point (robust scale from
the MAD), then blocks are selected up to `budget`, spread evenly over the strata
(depth, command, ventilated): every stratum gets the same quota, quota left unused by small
strata goes to the others (water filling), and within a stratum blocks are taken evenly in
time. All choices are deterministic.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

HUBER_K = 1.345
MAD_TO_SD = 1.4826
X_COLUMNS = ("speed_rpm", "current_a", "depth_m")


@dataclass
class TrainingSet:
    """Selected blocks: inputs, target, weights, and context columns for export."""

    x: np.ndarray  # (n, 3): speed_rpm, current_a, depth_m
    xf: np.ndarray  # (n, 3): GP inputs speed_rpm, shortfall_thrust_n, depth_m
    y: np.ndarray  # f_measured - f_BETM (N)
    w: np.ndarray  # Huber weights in (0, 1]
    t_s: np.ndarray
    command: np.ndarray
    ventilated: np.ndarray
    thrust_n: np.ndarray
    betm_n: np.ndarray
    run_id: np.ndarray
    provenance: dict = field(default_factory=dict)
    # "event", "outside", "edge" or "step" per row, by the detected events (as the evaluation
    # classifies by true ones); None in sets stored before it existed
    block_class: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.y)

    def take(self, index: np.ndarray) -> TrainingSet:
        """The rows `index` (provenance copied)."""
        return TrainingSet(**{k: _rows(getattr(self, k), index) for k in _ARRAYS},
                           provenance=dict(self.provenance))


_ARRAYS = [k for k in TrainingSet.__dataclass_fields__ if k != "provenance"]


def _rows(a: np.ndarray | None, index: np.ndarray) -> np.ndarray | None:
    """a[index], None for a column the set does not have."""
    return None if a is None else a[index]


def huber_weights(y: np.ndarray, segment: np.ndarray, window: int = 5) -> tuple[np.ndarray, float]:
    """Huber weights min(1, k s / |r|), r = y minus its running median within each segment."""
    from scipy.ndimage import median_filter

    r = np.empty_like(y, dtype=float)
    for s in np.unique(segment):
        idx = np.flatnonzero(segment == s)
        r[idx] = y[idx] - median_filter(y[idx], size=min(window, idx.size), mode="nearest")
    scale = MAD_TO_SD * float(np.median(np.abs(r - np.median(r))))
    scale = max(scale, 1e-9)
    with np.errstate(divide="ignore"):
        w = np.minimum(1.0, HUBER_K * scale / np.abs(r))
    return w, scale


def stratified_pick(strata: np.ndarray, budget: int) -> np.ndarray:
    """Indices (sorted) of at most `budget` rows, equal quotas per stratum, even in order."""
    keys, inverse, counts = np.unique(strata, return_inverse=True, return_counts=True)
    if counts.sum() <= budget:
        return np.arange(strata.size)
    quota = _water_fill(counts, budget)
    picked = []
    for k in range(keys.size):
        idx = np.flatnonzero(inverse == k)
        if quota[k] >= idx.size:
            picked.append(idx)
        elif quota[k] > 0:
            pos = np.floor((np.arange(quota[k]) + 0.5) * idx.size / quota[k]).astype(int)
            picked.append(idx[pos])
    return np.sort(np.concatenate(picked))


def _water_fill(counts: np.ndarray, budget: int) -> np.ndarray:
    """Per-stratum quotas summing to min(budget, total): equal shares, capped by counts."""
    quota = np.zeros(counts.size, dtype=int)
    left = budget
    open_ = np.ones(counts.size, bool)
    while left > 0 and open_.any():
        share = max(left // int(open_.sum()), 1)
        for k in np.flatnonzero(open_):
            add = min(share, counts[k] - quota[k], left)
            quota[k] += add
            left -= add
            if quota[k] >= counts[k]:
                open_[k] = False
            if left == 0:
                break
    return quota


def strata_keys(depth_m: np.ndarray, command: np.ndarray, ventilated: np.ndarray) -> np.ndarray:
    """One string key per row: depth|command|ventilated."""
    return np.array([f"{d:.3f}|{c:.3f}|{int(v)}" for d, c, v in
                     zip(depth_m, command, ventilated, strict=True)])


def concat(sets: list[TrainingSet]) -> TrainingSet:
    """Rows of several training sets (e.g. several runs) as one."""
    runs = [s.provenance.get("run_ids", []) for s in sets]
    prov = {**sets[0].provenance, "run_ids": [r for rs in runs for r in rs]}
    cols = {k: [getattr(s, k) for s in sets] for k in _ARRAYS}
    return TrainingSet(**{k: None if any(a is None for a in v) else np.concatenate(v)
                          for k, v in cols.items()}, provenance=prov)
