"""ROS 2 parameters for any node (`/**: ros__parameters: rigtool:`): coefficients per
direction, dead band, time constants, command range and the thrust -> command map."""

from __future__ import annotations

import math

import numpy as np

from rigtool.artefacts.vehicle import ExportInput, model_text, no_dynamics
from rigtool.artefacts.yaml_params import comment, yaml_entries

FILE = "thruster_params.yaml"
FOLLOWS = "ROS 2 parameter files as rclcpp reads them (Humble and later)"


def needs(x: ExportInput) -> list[str]:
    """Nothing beyond the calibration."""
    return []


def direction_map(x: ExportInput, direction: str) -> tuple[list[float], list[float], list[int]]:
    """(thrust ascending, command, index each branch starts at) of one direction's branches
    in thrust order; a branch whose thrust range overlaps one taken before is left out (the
    first branch holding a thrust gives its command, as in cal.command)."""
    taken: list[tuple[np.ndarray, np.ndarray]] = []
    for d, f, c in x.map.tables:
        if d == direction and f.size and not any(
                f[0] <= g[-1] and g[0] <= f[-1] for g, _ in taken):
            taken.append((f, c))
    taken.sort(key=lambda fc: float(fc[0][0]))
    starts = [int(v) for v in np.cumsum([0] + [f.size for f, _ in taken])[:-1]]
    return ([float(v) for f, _ in taken for v in f], [float(v) for _, c in taken for v in c],
            starts)


def render(x: ExportInput) -> str:
    """The parameter file's text; a key whose list would be empty is left out (rclcpp cannot
    read an empty list), and n_dead_zones / has_forward_map / has_reverse_map say so."""
    zones = x.dead_zones
    params: dict = {
        **x.texts,
        "depth_m": math.nan if x.sec.depth_m is None else float(x.sec.depth_m),
        "neutral_command": float(x.cal.neutral_command),
        "n_dead_zones": len(zones),
        "dead_band": [float(v) for z in zones for v in z],
        "thrust_coefficient_forward": x.coef("C_p_fwd"),
        "thrust_coefficient_reverse": x.coef("C_p_rev"),
        "thrust_coefficient_unit": "N/(r/min)^2, f = C |n| n",
    }
    for direction in ("forward", "reverse"):
        f, c, starts = direction_map(x, direction)
        params[f"has_{direction}_map"] = bool(len(f))
        params[f"map_{direction}_thrust_n"] = [float(v) for v in f]
        params[f"map_{direction}_command"] = [float(v) for v in c]
        if len(starts) > 1:
            params[f"map_{direction}_branch_start"] = starts
    dyn = x.dynamics_params()
    params |= {"dynamics_model": "none"} if dyn is None else dyn
    notes = [*x.head(list(x.texts)),
             "map_*: thrust (N, ascending) -> command; interpolate linearly; neutral for 0 N;",
             "by |thrust|: beyond a map's largest its command there, below its smallest the",
             "neutral command. Where a direction has several branches (a dead zone between them),",
             "map_*_branch_start gives the index each begins at: interpolate within one, and",
             "between two take the nearer end. A list that would be empty is left out",
             "(has_*_map, n_dead_zones: 0).",
             "NaN (.nan) marks a value this run could not give."]
    notes += ([f"dynamics: {model_text(dyn)}."] if dyn is not None else
              [f"dynamics_model none: {no_dynamics(x.dynamics)}, so there are no time "
               "constants."])
    return (comment(notes) + "/**:\n  ros__parameters:\n    rigtool:\n"
            + yaml_entries(params, " " * 6))
