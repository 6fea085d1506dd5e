"""Where an exported thrust model may be trusted: physical bounds and the training domain.

Numpy only, like the rest of rigtool.models; the values are set when the model is fitted
(rigtool.analysis.qctm_export) and stored in qctm_gp.json.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# Per-block flags of a prediction (a bit field, also written by the C evaluator)
OUT_OF_DOMAIN = 1  # an input outside the training ranges, or far from every training row
CURRENT_FAULT = 2  # shortfall outside bounds.shortfall: fell back to the speed estimate
CLAMPED = 4  # the corrected thrust was held to [0, f_BETM + above_n] (direction of the speed)

DOMAIN_INPUTS = ("speed_rpm", "current_a", "depth_m", "shortfall_thrust_n")
# Ventilation lowers the current by at most ~10 % (twin 2-6 %, [Luo2020] similar) and a 0.2 s
# block's shortfall scatters by < 0.1 without it: beyond this range the current is not a
# ventilating propeller's but a dropout, a current below idle or a wrong speed reading.
DEFAULT_SHORTFALL = (-0.2, 0.3)
DEFAULT_MAX_DISTANCE = 1.0  # standardised GP-input units (one training-set std)


@dataclass(frozen=True)
class Bounds:
    """Physics limits: admissible block shortfall and how far above f_BETM thrust may read."""

    shortfall: tuple[float, float] = DEFAULT_SHORTFALL
    above_n: float = float("inf")  # inf in files older than format 4: no upper clamp

    def to_dict(self) -> dict:
        above = self.above_n if np.isfinite(self.above_n) else None
        return {"shortfall": list(self.shortfall), "above_n": above}

    @classmethod
    def from_dict(cls, d: dict | None) -> Bounds:
        if not d:
            return cls()
        lo, hi = d.get("shortfall", DEFAULT_SHORTFALL)
        above = d.get("above_n")  # null (JSON has no inf): no upper clamp
        return cls((float(lo), float(hi)), float("inf") if above is None else float(above))


@dataclass(frozen=True)
class Domain:
    """Per-input [lo, hi] ranges of the training data and the largest distance (standardised
    GP inputs) from the nearest training row at which predictions are still trusted."""

    ranges: dict[str, tuple[float, float]] = field(default_factory=dict)
    max_distance: float = DEFAULT_MAX_DISTANCE

    def outside(self, values: dict[str, np.ndarray]) -> np.ndarray:
        """True where any input lies outside its range (inputs without a range pass)."""
        size = len(np.atleast_1d(next(iter(values.values())))) if values else 0
        out = np.zeros(size, bool)
        for name, (lo, hi) in self.ranges.items():
            v = np.asarray(values[name], dtype=float)
            out |= ~((v >= lo) & (v <= hi))
        return out

    def to_dict(self) -> dict:
        return {"inputs": list(self.ranges), "ranges": {k: list(v) for k, v in self.ranges.items()},
                "max_distance": self.max_distance,
                "distance": "min over training rows of || (x - x_train_j) / gp.x_scale ||"}

    @classmethod
    def from_dict(cls, d: dict | None) -> Domain | None:
        if not d:
            return None
        return cls({k: (float(v[0]), float(v[1])) for k, v in d["ranges"].items()},
                   float(d.get("max_distance", DEFAULT_MAX_DISTANCE)))


def nearest_distance(x: np.ndarray, x_train: np.ndarray, x_mean: np.ndarray,
                     x_scale: np.ndarray, chunk: int = 2048) -> np.ndarray:
    """Euclidean distance of each row of x to its nearest training row, standardised inputs."""
    xs = (np.atleast_2d(np.asarray(x, float)) - x_mean) / x_scale
    xt = (np.asarray(x_train, float) - x_mean) / x_scale
    out = np.empty(len(xs))
    for s in range(0, len(xs), chunk):
        d = xs[s:s + chunk, None, :] - xt[None, :, :]
        out[s:s + chunk] = np.sqrt(np.min(np.sum(d * d, axis=-1), axis=1))
    return out
