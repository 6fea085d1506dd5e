"""What the vehicle-simulator formats share: their options, exact numbers, the parameters a
block needs and the FRD -> FLU position change (docs/vehicle-formats.md)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from rigtool.artefacts.encode import xml_text
from rigtool.artefacts.vehicle_model import GROUPS


@dataclass(frozen=True)
class HydroOptions:
    """Where the block goes in the user's vehicle: the link it acts on and, for consumers
    that take one, the namespace (gz-sim: the ocean-current topic's)."""

    link: str
    namespace: str | None = None


def num(v: float) -> str:
    """A number exactly as Python holds it (repr: the shortest text that reads back to the
    same double; C++'s stod and SDFormat read it)."""
    x = float(v)
    if not math.isfinite(x):
        raise ValueError(f"not a finite number: {x!r}")
    return repr(x)


def numbers(values: Sequence[float]) -> str:
    """Space-separated exact numbers."""
    return " ".join(num(v) for v in values)


def value(model: dict[str, Any], name: str) -> float | None:
    """The value of one hydrodynamic derivative (X_udot, Y_v, N_rr, ...), None if missing."""
    for group, names in GROUPS.items():
        if name in names:
            return model["hydrodynamics"][group][name]["value"]
    raise KeyError(name)


def values(model: dict[str, Any], group: str) -> list[float]:
    """The six diagonal values of one group (added_mass, linear_damping, quadratic_damping);
    call only when `missing` found none null."""
    return [float(model["hydrodynamics"][group][n]["value"]) for n in GROUPS[group]]


def missing(model: dict[str, Any], groups: Sequence[str]) -> list[str]:
    """A reason for each null derivative of `groups` the block needs, with the model's own
    reason why it was not identified."""
    out = []
    for group in groups:
        for name in GROUPS[group]:
            p = model["hydrodynamics"][group][name]
            if p["value"] is None:
                why = _printable(p.get("reason") or "no reason given")
                out.append(f"{name} ({group}) was not identified ({why}); the block needs "
                           "every diagonal term")
    return out


def _printable(text: str, limit: int = 200) -> str:
    """Stored text for a one-line message: line breaks as spaces, other controls and format
    characters as \\u escapes, cut to `limit` characters."""
    flat = " ".join(text.split())[:limit]
    return "".join(c if c.isprintable() else f"\\u{ord(c):04x}" for c in flat)


def link_needs(options: HydroOptions) -> list[str]:
    """Why there is no link name."""
    if not options.link or not options.link.strip():
        return ["no link: give the link name (the vehicle's body link in your model)"]
    return []


def frd_to_flu(v: Sequence[float]) -> list[float]:
    """A position in the body's FRD axes in Gazebo's link axes (x forward, y left, z up):
    a half turn about x, so y and z change sign (the diagonal derivatives do not)."""
    return [float(v[0]), 0.0 - float(v[1]), 0.0 - float(v[2])]  # 0.0 - y: no "-0.0"


def text_element(tag: str, text: str, indent: str) -> str:
    """One element holding user text, encoded (never in a comment)."""
    return f"{indent}<{tag}>{xml_text(text)}</{tag}>\n"


def comment(text: str) -> str:
    """A one-line XML comment of fixed text and numbers (no user text): `--` cannot occur."""
    return "<!-- " + " ".join(text.replace("--", "- -").split()) + " -->\n"
