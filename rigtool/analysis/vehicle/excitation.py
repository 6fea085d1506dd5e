"""Whether the logs excite each parameter asked for, and in plain words why not.

Three questions per degree of freedom, asked before any fit:
- was it moved at all (its velocity beyond its own noise)?
- was it moved both ways (the linear and quadratic damping terms are told apart by a
  velocity that reverses; one-way, u and u|u| are near collinear)?
- was it accelerated (added mass shows only while the velocity changes)?
"""

from __future__ import annotations

import numpy as np

from rigtool.analysis.vehicle.model import ADDED, DOFS, LINEAR, QUADRATIC, UNITS, VELOCITY
from rigtool.analysis.vehicle.segments import Prepared

MOVED_NOISE = 5.0  # the velocity's 99th percentile must exceed this many noise sigmas
REVERSED_FRAC = 0.2  # each direction must reach this fraction of the other
ACCELERATED_FRAC = 0.03  # RMS of m nu' against RMS of the forces it balances


def problems(prep: Prepared, rigid_diagonal: np.ndarray, dofs: list[int]) -> list[str]:
    """One sentence per parameter the logs cannot identify, naming it and the reason."""
    out = []
    for i in dofs:
        x, name, unit = prep.smooth[:, i], VELOCITY[i], UNITS[i]
        top, bottom = float(np.percentile(x, 99.5)), float(np.percentile(x, 0.5))
        reach = max(abs(top), abs(bottom))
        if reach < MOVED_NOISE * prep.noise[i] or reach == 0.0:
            out.append(f"{DOFS[i]} never excited: {name} stays within {reach:.3g} {unit} "
                       f"(noise {prep.noise[i]:.2g} {unit}), so {ADDED[i]}, {LINEAR[i]} and "
                       f"{QUADRATIC[i]} cannot be identified")
            continue
        if min(top, -bottom) < REVERSED_FRAC * reach:
            out.append(f"{DOFS[i]} never reversed ({name} from {bottom:.3g} to {top:.3g} {unit}), "
                       f"so {LINEAR[i]} and {QUADRATIC[i]} cannot be told apart")
        inertial = rigid_diagonal[i] * prep.nu_dot[:, i]
        forces = prep.tau[:, i] - np.mean(prep.tau[:, i])
        if np.sqrt(np.mean(inertial**2)) < ACCELERATED_FRAC * np.sqrt(np.mean(forces**2)):
            out.append(f"{DOFS[i]} never accelerated enough ({name} nearly steady throughout), "
                       f"so the added mass {ADDED[i]} cannot be identified")
    return out
