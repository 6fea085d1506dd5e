"""Safety limits checked on every sample block, with a debounce so one noisy sample cannot trip."""

from __future__ import annotations

import numpy as np

from rigtool.errors import SafetyTrip
from rigtool.protocol import Limits


def _run_lengths(mask: np.ndarray, carry: int) -> tuple[int, int]:
    """Longest run of True in `mask` continuing a run of `carry` before it; and the trailing run."""
    if mask.size == 0:
        return carry, carry
    if mask.all():
        total = carry + mask.size
        return total, total
    false_idx = np.flatnonzero(~mask)
    lead = carry + int(false_idx[0])
    trail = int(mask.size - 1 - false_idx[-1])
    edges = np.diff(false_idx) - 1
    inner = int(edges.max()) if edges.size else 0
    return max(lead, trail, inner), trail


class LimitMonitor:
    """Trips (raises SafetyTrip) when a quantity exceeds its limit for `debounce` samples in a row.

    Each quantity is counted in its own samples: force samples for thrust, feedback frames
    for current and speed.
    """

    def __init__(self, limits: Limits) -> None:
        self.debounce = limits.debounce_samples
        self.checks = {
            name: lim for name, lim in (
                ("thrust_n", limits.max_thrust_n),
                ("current_a", limits.max_current_a),
                ("speed_rpm", limits.max_speed_rpm),
            ) if lim is not None
        }
        self._carry = dict.fromkeys(self.checks, 0)

    def check(self, values: dict[str, np.ndarray | None]) -> None:
        for name, limit in self.checks.items():
            v = values.get(name)
            if v is None:
                continue
            mask = np.abs(v) > limit  # NaN compares False: missing feedback never trips
            if not mask.any():
                self._carry[name] = 0
                continue
            longest, self._carry[name] = _run_lengths(mask, self._carry[name])
            if longest >= self.debounce:
                peak = float(np.nanmax(np.abs(v)))
                raise SafetyTrip(f"limit trip: |{name}| reached {peak:.3g}, above the limit "
                                 f"{limit:g} for {longest} samples in a row")

    def reset(self) -> None:
        self._carry = dict.fromkeys(self.checks, 0)
