"""Which section of a calibration is used when none is named: the deepest depth set (the
thruster's own thrust; shallower points may ventilate) and there the middle supply voltage.
One rule for the vehicle artefacts (artefacts/vehicle.py), the Python API and the dataset."""

from __future__ import annotations

import math
from collections.abc import Sequence


def deepest_depth(depths: Sequence[float | None]) -> float | None:
    """The deepest depth set, else the first (not set)."""
    known = [d for d in depths if d is not None]
    return max(known) if known else depths[0]


def middle_voltage(voltages: Sequence[float | None]) -> int:
    """Index of the middle supply voltage among one depth's sections (None sorts first)."""
    order = sorted(range(len(voltages)),
                   key=lambda i: -math.inf if voltages[i] is None else voltages[i])
    return order[(len(order) - 1) // 2]


def default_section(depths: Sequence[float | None], voltages: Sequence[float | None]) -> int:
    """Index of the default section among sections at `depths` and `voltages` (pairwise)."""
    depth = deepest_depth(depths)
    here = [i for i, d in enumerate(depths) if d == depth]
    return here[middle_voltage([voltages[i] for i in here])]
