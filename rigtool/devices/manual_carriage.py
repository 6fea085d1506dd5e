"""A flow or tow speed set by the operator on request (a flume without a remote pump control)."""

from __future__ import annotations

import sys
from collections.abc import Callable

from rigtool.devices.base import Device
from rigtool.errors import UsageError


class ManualCarriage(Device):
    """Prompts the operator at the terminal to set each speed and angle, and to stop the flow."""

    reached_by = "operator"

    def __init__(self, ask: Callable[[str], str] = input, interactive: bool | None = None) -> None:
        self._ask = ask
        self._interactive = sys.stdin.isatty() if interactive is None else interactive
        self._moving = False

    def set_flow(self, speed_mps: float, angle_deg: float) -> tuple[float, float]:
        """Ask for the setting; an empty answer confirms it, a number is the speed read (m/s)."""
        if not self._interactive:
            raise UsageError(f"the flow ({speed_mps:g} m/s at {angle_deg:g} deg) must be set by "
                             "hand, but there is no terminal to ask on; run interactively, or "
                             "give the rig a `carriage:` section and `captive: {mode: preset}`")
        answer = self._ask(f"Set the flow to {speed_mps:g} m/s with the vehicle at "
                           f"{angle_deg:g} deg, then press Enter (or type the speed read in "
                           "m/s): ").strip()
        self._moving = True
        if not answer:
            return speed_mps, angle_deg
        try:
            return float(answer), angle_deg
        except ValueError:
            raise UsageError(f"expected a speed in m/s or an empty answer, got {answer!r}") from None

    def stop(self) -> None:
        """Tell the operator to stop the flow (nothing can confirm it)."""
        if self._moving:
            print("STOP THE FLOW (speed 0) NOW.", file=sys.stderr)
            self._moving = False

    def _safe_state(self) -> None:
        self.stop()
