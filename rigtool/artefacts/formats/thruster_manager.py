"""ROS 2 parameters of CentraleNantesROV thruster_manager: its thrust limits tam.min_thrust,
tam.max_thrust and the dead zone to avoid, tam.deadzone, all in N (docs/formats-controllers.md)."""

from __future__ import annotations

from rigtool.artefacts.vehicle import ExportInput
from rigtool.artefacts.yaml_params import comment, yaml_entries

FILE = "thruster_manager.yaml"
FOLLOWS = ("CentraleNantesROV/thruster_manager bd7d7c9 (2025-04-10): "
           "include/thruster_manager/thruster_manager.h parseRobotDescription (declares "
           "tam.min_thrust, tam.max_thrust, tam.deadzone as doubles), src/thruster_manager.cpp "
           "scale()")


def needs(x: ExportInput) -> list[str]:
    """Both directions: thruster_manager takes a negative minimum and a positive maximum, and a
    zero limit switches its scaling off (scale() returns when either is 0)."""
    missing = [d for d in ("forward", "reverse") if x.map.limits(d) is None]
    return [f"command curve: no {d} branch, and thruster_manager needs a {d} thrust limit "
            "(tam.min_thrust < 0 < tam.max_thrust; a zero limit turns its limits off)"
            for d in missing]


def limits(x: ExportInput) -> dict[str, float]:
    """tam.min_thrust (minus the largest reverse thrust), tam.max_thrust (the largest forward
    thrust) and tam.deadzone (the larger of the two directions' smallest thrust outside the
    dead band: below it the vehicle map gives the neutral command), in N."""
    fwd, rev = x.map.limits("forward"), x.map.limits("reverse")
    return {"min_thrust": -rev[1], "max_thrust": fwd[1], "deadzone": max(fwd[0], rev[0])}


def render(x: ExportInput) -> str:
    """The parameter file: `tam.*` for every node (`/**`), and the stored texts beside them
    under `rigtool.` as quoted YAML strings (a node that does not declare them ignores them)."""
    notes = [*x.head([f"rigtool.{k}" for k in x.texts]),
             "thruster_manager scales every thrust into [tam.min_thrust, tam.max_thrust] and",
             "avoids |thrust| < tam.deadzone when its allocation has a kernel. Replace /** by",
             "the node's name to give these to it alone."]
    return (comment(notes) + "/**:\n  ros__parameters:\n    tam:\n"
            + yaml_entries(limits(x), " " * 6) + "    rigtool:\n"
            + yaml_entries(x.texts, " " * 6))
