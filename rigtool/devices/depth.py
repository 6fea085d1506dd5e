"""Depth stages without a motor: depth fixed by the rig, or set by the operator on request."""

from __future__ import annotations

import sys
from collections.abc import Callable

from rigtool.devices.base import Device
from rigtool.errors import UsageError


class PresetDepth(Device):
    """The rig's one fixed depth, as the protocol declares it; nothing moves or confirms it."""

    reached_by = "preset"

    def move_to(self, depth_m: float) -> None:
        """Nothing to move; None, because nobody reported a depth reached."""
        return None


class ManualDepth(Device):
    """Prompts the operator at the terminal to set the truss and confirm."""

    reached_by = "operator"

    def __init__(self, ask: Callable[[str], str] = input, interactive: bool | None = None) -> None:
        self._ask = ask
        self._interactive = sys.stdin.isatty() if interactive is None else interactive

    def move_to(self, depth_m: float) -> float:
        if not self._interactive:
            raise UsageError(
                f"depth {depth_m:.3f} m must be set by hand, but there is no terminal to ask on; "
                "run interactively, or declare `depth: {mode: preset}` if the depth is fixed"
            )
        answer = self._ask(
            f"Set the propeller centre to {depth_m * 100:.1f} cm below the surface, "
            "then press Enter (or type the depth reached in cm): "
        ).strip()
        if not answer:
            return depth_m
        try:
            return float(answer) / 100.0
        except ValueError:
            raise UsageError(f"expected a depth in cm or an empty answer, got {answer!r}") from None
