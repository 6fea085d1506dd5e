"""Clocks: the real monotonic clock, and a virtual one that makes simulated sweeps fast."""

from __future__ import annotations

import time


class RealClock:
    """Wall-clock time from time.monotonic()."""

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)


class VirtualClock:
    """A clock that only moves when someone sleeps on it: hours of sweep in seconds."""

    def __init__(self, start: float = 0.0) -> None:
        self._t = float(start)

    def now(self) -> float:
        return self._t

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            self._t += seconds

    def advance_to(self, t: float) -> None:
        """Move to `t` if it lies in the future (used by simulated devices)."""
        if t > self._t:
            self._t = t
