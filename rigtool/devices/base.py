"""The small interfaces the engine drives, the sample blocks they exchange, and `Device`,
the base every driver builds on.

Every driver, real or simulated, implements one of the interfaces and subclasses `Device`.
Units are SI with the unit in the name; commands are in the actuator's native unit
(percent, PWM counts, pulse width in us, r/min or A).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Protocol, Self, runtime_checkable

import numpy as np


class Device:
    """What every driver shares (as python-can's BusABC does for buses): a `close` that is
    idempotent and callable from any exit path, use as a context manager, and default
    diagnostics.

    A driver fills two hooks. `_safe_state` runs first, with the transport still open
    (neutral, output off); `_release` runs once after it even when it failed (stop threads,
    close the port), and the safe state's error is raised then. A driver that keeps
    counters replaces `stats` (an attribute or a property).
    """

    name: str = "device"
    stats: Mapping[str, int | float] = MappingProxyType({})  # counters since open
    stats_gauges: tuple[str, ...] = ()  # keys of `stats` that are states, not counters
    _closed: bool = False

    def close(self) -> None:
        """Leave the device safe and release its transport; a second call does nothing."""
        if self._closed:
            return
        try:
            self._safe_state()
        finally:
            self._closed = True
            self._release()

    def pop_warnings(self) -> list[str]:
        """Warnings since the previous call, oldest first (none by default)."""
        return []

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _safe_state(self) -> None:
        """Put the device in its safe state while the transport is open (nothing by default)."""

    def _release(self) -> None:
        """Release threads and transport, once (nothing by default)."""


@dataclass
class ForceBlock:
    """Samples from a force sensor: times (s, run clock) and six F/T channels (N, N m).

    Sensors with fewer channels fill the others with NaN. `seq` is the device's own
    sample sequence number where it has one (else a running count), so lost samples
    can be reconciled.
    """

    t_s: np.ndarray
    ft: np.ndarray  # shape (n, 6): fx, fy, fz, tx, ty, tz
    seq: np.ndarray | None = None
    temperature_c: np.ndarray | None = None  # an auxiliary channel of the sensor's, per sample

    def __len__(self) -> int:
        return len(self.t_s)


@dataclass
class FeedbackBlock:
    """Actuator feedback samples (any field may be None when the driver lacks it)."""

    t_s: np.ndarray
    speed_rpm: np.ndarray | None = None
    current_a: np.ndarray | None = None
    voltage_v: np.ndarray | None = None
    fault: str | None = None
    temperature_c: np.ndarray | None = None  # an auxiliary channel (limits only; not stored)

    def __len__(self) -> int:
        return len(self.t_s)


@dataclass(frozen=True)
class ActuatorInfo:
    """What the engine needs to know about an actuator's command space."""

    command_unit: str
    neutral: float
    command_min: float
    command_max: float
    feedback: tuple[str, ...] = field(default=())  # subset of speed_rpm, current_a, voltage_v, temperature_c


@runtime_checkable
class Actuator(Protocol):
    """Sets a command; can always be put in its safe neutral state.

    Optionally, `expected_speed_rpm(command) -> float | None` gives the steady speed a
    command should produce where the driver knows it (speed control, the twin's map);
    the engine then checks that the speed feedback follows (rigtool/safety.py).
    """

    info: ActuatorInfo

    def set_command(self, value: float) -> None:
        """Command `value` in `info.command_unit`."""

    def neutral(self) -> None:
        """Go to the safe neutral command. Idempotent, callable from any exit path."""

    def read_feedback(self) -> FeedbackBlock:
        """Feedback received since the previous call (may be empty)."""

    def close(self) -> None:
        """Release the transport (after neutral)."""


@runtime_checkable
class ForceSensor(Protocol):
    """Streams timestamped F/T blocks; can be tared."""

    channels: tuple[str, ...]

    def read(self, n: int, rate_hz: float) -> ForceBlock:
        """Block until `n` samples at `rate_hz` are available and return them."""

    def set_bias(self, bias: np.ndarray) -> None:
        """Subtract `bias` (6 values, N and N m) from every later sample."""

    def close(self) -> None:
        """Release the transport."""


@runtime_checkable
class DepthStage(Protocol):
    """Puts the propeller centre at a depth below the surface (m)."""

    reached_by: str  # who reports the depth reached: "stage", "operator", "simulator", "preset"

    def move_to(self, depth_m: float) -> float | None:
        """Move (or have the operator move) to `depth_m`; return the depth reached as the
        device or the operator reported it, or None when nothing confirmed it."""

    def close(self) -> None:
        """Release the transport."""


@runtime_checkable
class Supply(Protocol):
    """Sets the thruster's supply voltage (V) for a voltage sweep."""

    reached_by: str  # who reports the voltage reached: "supply", "operator", "simulator"

    def set_voltage(self, volts: float) -> float | None:
        """Set (or have the operator set) `volts`; return the voltage measured, or None."""

    def safe(self) -> None:
        """Output off, or the rig file's safe voltage; idempotent."""

    def close(self) -> None:
        """Leave the output safe and release the transport."""


@runtime_checkable
class Carriage(Protocol):
    """Sets the flow or tow speed (m/s, signed) and the held vehicle's angle (deg) of a captive
    run: a towing carriage, a flume pump with a rotary stage."""

    reached_by: str  # who reports the setting reached: "carriage", "operator", "simulator"

    def set_flow(self, speed_mps: float, angle_deg: float) -> tuple[float | None, float | None]:
        """Stop if the angle changes, turn, then reach `speed_mps`; return (speed, angle)
        reached as reported, None where nothing reported it."""

    def stop(self) -> None:
        """Speed 0: the safe state. Idempotent, callable from any exit path."""

    def close(self) -> None:
        """Stop and release the transport."""


@runtime_checkable
class Clock(Protocol):
    """Monotonic time source; the simulator injects a virtual one."""

    def now(self) -> float:
        """Seconds on a monotonic scale."""

    def sleep(self, seconds: float) -> None:
        """Wait `seconds` (a virtual clock just advances)."""
