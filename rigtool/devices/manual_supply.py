"""A supply set by hand: the operator sets each voltage of the sweep and confirms it."""

from __future__ import annotations

import sys
from collections.abc import Callable

from rigtool.devices.base import Device
from rigtool.errors import UsageError


class ManualSupply(Device):
    """Prompts the operator at the terminal to set the supply voltage and confirm."""

    reached_by = "operator"

    def __init__(self, ask: Callable[[str], str] = input, interactive: bool | None = None) -> None:
        self._ask = ask
        self._interactive = sys.stdin.isatty() if interactive is None else interactive

    def set_voltage(self, volts: float) -> float | None:
        """Ask for `volts`; return the voltage the operator read off the supply, or None when
        they just confirmed."""
        if not self._interactive:
            raise UsageError(f"the supply must be set to {volts:g} V by hand, but there is no "
                             "terminal to ask on; run interactively, or use `voltage: {mode: "
                             "preset}` with a `supply:` in the rig file")
        answer = self._ask(f"Thruster at neutral. Set the supply to {volts:g} V, then press "
                           "Enter (or type the voltage it shows): ").strip()
        if not answer:
            return None
        try:
            return float(answer)
        except ValueError:
            raise UsageError(f"expected a voltage or an empty answer, got {answer!r}") from None

    def safe(self) -> None:
        """Nothing to switch: the operator owns the supply."""
