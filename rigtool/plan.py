"""Expand a protocol into a Plan: every step known before the run starts."""

from __future__ import annotations

import random
from dataclasses import asdict, dataclass

from rigtool.protocol import Protocol

DEPTH_MOVE_S = 10.0  # time budgeted per depth change in duration estimates


@dataclass(frozen=True)
class PlanStep:
    """One point of a sweep: command at a depth, which repeat, which sweep direction."""

    idx: int
    command: float
    depth_m: float
    repeat: int
    direction: str  # "up", "down" or "random"

    def as_dict(self) -> dict:
        return asdict(self)


def _command_sequence(protocol: Protocol, repeat: int) -> list[tuple[float, str]]:
    axis = protocol.command
    values = axis.command_values()
    if axis.order == "up":
        return [(v, "up") for v in values]
    if axis.order == "down":
        return [(v, "down") for v in reversed(values)]
    if axis.order == "up-down":
        return [(v, "up") for v in values] + [(v, "down") for v in reversed(values)]
    shuffled = list(values)
    random.Random(axis.seed * 1_000_003 + repeat).shuffle(shuffled)
    return [(v, "random") for v in shuffled]


def expand(protocol: Protocol) -> list[PlanStep]:
    """All steps in execution order: depth outer (default) or inner, repeats, command order."""
    depths = protocol.depth.depths_m()
    repeats = range(protocol.command.repeats)
    combos: list[tuple[float, int, float, str]] = []
    if protocol.depth.loop == "outer":
        for depth in depths:
            for rep in repeats:
                combos += [(depth, rep, c, d) for c, d in _command_sequence(protocol, rep)]
    else:
        for rep in repeats:
            for c, d in _command_sequence(protocol, rep):
                combos += [(depth, rep, c, d) for depth in depths]
    return [PlanStep(i, c, depth, rep, d) for i, (depth, rep, c, d) in enumerate(combos)]


def estimate_duration_s(protocol: Protocol, plan: list[PlanStep], neutral: float | None = None) -> float:
    """Upper-bound estimate of the run's duration from the timing block and slew limit."""
    timing = protocol.timing
    per_point = (timing.settle.max_seconds() + timing.acquire.n_samples / timing.acquire.rate_hz
                 + timing.rest_s)
    total = per_point * len(plan)
    slew = protocol.limits.slew_per_s
    if slew and neutral is not None:
        total += sum(2 * abs(s.command - neutral) / slew for s in plan)
    depth_changes = 1 + sum(1 for a, b in zip(plan, plan[1:], strict=False) if a.depth_m != b.depth_m)
    total += depth_changes * DEPTH_MOVE_S
    if timing.tare == "per_point":
        total += timing.tare_s * len(plan)
    elif timing.tare == "per_depth":
        total += timing.tare_s * depth_changes
    elif timing.tare == "at_start":
        total += timing.tare_s
    return total
