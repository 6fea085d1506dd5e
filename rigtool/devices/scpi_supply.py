"""Programmable bench power supply over SCPI (Keysight E36xx, Rigol DP8xx, R&S HMP, Korad in
SCPI mode): the supply-voltage axis of a sweep (docs/drivers/scpi-supply.md).

Talks over any pyserial URL: a serial port, or `socket://host:port` for a LAN supply's raw
SCPI socket (port 5025 on most). Every setting is confirmed: after `VOLT`, `CURR` or `OUTP`
the driver reads `SYST:ERR?` and the setting back, so a refused or lost command is an error,
not a silent difference. Voltage changes are ramped at `slew_v_per_s`. `safe()` (and
`close()`) turns the output off or goes to `safe_voltage_v`, as the rig file asks; it is
idempotent. Lines that are not ASCII or not a number where one is expected are counted as
garbage and skipped.
"""

from __future__ import annotations

import contextlib
import math
import re
import time
from collections.abc import Callable
from typing import Annotated, Literal

import serial
from pydantic import BaseModel, ConfigDict, Field

from rigtool.bounds import Baudrate, PositiveSeconds
from rigtool.devices.framing import LineFramer
from rigtool.errors import DeviceError, UsageError

_MAX_LINE = 256
_ERROR_REPLY = re.compile(r"[+-]?\d+,")  # SYST:ERR? answers `code,"message"`
_RAMP_STEP_S = 0.05  # a ramp sends a new setpoint this often
Volts = Annotated[float, Field(ge=0, le=1000, allow_inf_nan=False)]
Amps = Annotated[float, Field(gt=0, le=1000, allow_inf_nan=False)]


class ScpiSupplyConfig(BaseModel):
    """Rig-file section for an SCPI supply (`driver: scpi-supply`)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    driver: Literal["scpi-supply"]
    url: str = Field(min_length=1)  # pyserial URL: /dev/ttyUSB0, socket://192.168.1.20:5025
    baudrate: Baudrate = 9600  # ignored by socket://
    timeout_s: PositiveSeconds = 1.0  # reply timeout
    max_voltage_v: Volts = 60.0  # refuse setpoints above this (the thruster's rating)
    current_limit_a: Amps = 10.0  # the supply's current limit (from the protocol's limits)
    slew_v_per_s: Annotated[float, Field(gt=0, le=1000, allow_inf_nan=False)] = 10.0
    on_exit: Literal["off", "safe_voltage"] = "off"  # what safe() leaves the output at
    safe_voltage_v: Volts = 0.0
    line_end: Literal["\n", "\r\n"] = "\n"


class ScpiSupply:
    """A supply the engine sets the bus voltage with; `measure()` reads it back."""

    reached_by = "supply"

    def __init__(self, config: ScpiSupplyConfig) -> None:
        self.config = config
        self.name = f"SCPI supply on {config.url}"
        self.stats = dict.fromkeys(("lines", "garbage", "timeouts", "errors"), 0)
        self._framer = LineFramer(_MAX_LINE)
        self._closed = False
        self._setpoint_v: float | None = None
        try:
            self._ser = serial.serial_for_url(config.url, baudrate=config.baudrate, timeout=0.02,
                                              write_timeout=config.timeout_s)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise DeviceError(f"cannot open {config.url} (SCPI supply): {exc}") from None
        try:
            self.identity = self._query("*IDN?")
            self._set(f"CURR {config.current_limit_a:.4f}", "CURR?", config.current_limit_a)
            self._setpoint_v = self._number("VOLT?")
        except BaseException:
            self._release()
            raise

    # -- what the engine uses -----------------------------------------------------------------
    def set_voltage(self, volts: float) -> float:
        """Ramp the setpoint to `volts` at the slew limit, switch the output on, and return
        the output voltage measured at the end."""
        if not (math.isfinite(volts) and 0.0 <= volts <= self.config.max_voltage_v):
            raise UsageError(f"{volts!r} V is outside 0..{self.config.max_voltage_v:g} V "
                             f"(max_voltage_v of {self.name})")
        start = self._setpoint_v if self._setpoint_v is not None else 0.0
        steps = max(1, math.ceil(abs(volts - start) / self.config.slew_v_per_s / _RAMP_STEP_S))
        t0 = time.monotonic()
        for k in range(1, steps + 1):
            target = start + (volts - start) * k / steps
            self._set(f"VOLT {target:.4f}", "VOLT?", target)
            self._setpoint_v = target
            if k < steps:
                time.sleep(max(0.0, t0 + k * _RAMP_STEP_S - time.monotonic()))
            if k == 1:
                self.output(True)
        return self.measure()[0]

    def output(self, on: bool) -> None:
        """Switch the output on or off (confirmed)."""
        self._set(f"OUTP {'ON' if on else 'OFF'}", "OUTP?", 1.0 if on else 0.0)

    def measure(self) -> tuple[float, float]:
        """(volts, amps) the supply measures at its output."""
        return self._number("MEAS:VOLT?"), self._number("MEAS:CURR?")

    def safe(self) -> None:
        """Output off (or ramped to safe_voltage_v), as the rig file asks; idempotent, quiet
        after close. DeviceError when the supply does not confirm it."""
        if self._closed:
            return
        if self.config.on_exit == "off":
            self.output(False)
        else:
            self.set_voltage(self.config.safe_voltage_v)

    def close(self) -> None:
        """Safe state, then release the port. Idempotent; a failed safe state is raised after
        the port is released."""
        if self._closed:
            return
        try:
            self.safe()
        finally:
            self._release()

    # -- internals ----------------------------------------------------------------------------
    def _release(self) -> None:
        self._closed = True
        with contextlib.suppress(serial.SerialException, OSError):
            self._ser.close()

    def _set(self, command: str, query: str, expect: float) -> None:
        """Send a setting, then check the error queue and the value read back."""
        self._write(command)
        error = self._query("SYST:ERR?", _ERROR_REPLY.match)
        if not error.startswith(("0,", "+0,")):
            self.stats["errors"] += 1
            raise DeviceError(f"{self.name} refused {command!r}: {error}")
        got = self._number(query)
        if abs(got - expect) > 1e-3 * max(1.0, abs(expect)):
            raise DeviceError(f"{self.name}: {query} reads {got:g} after {command!r}")

    def _write(self, line: str) -> None:
        if self._closed:
            raise DeviceError(f"{self.name} is closed")
        try:
            self._ser.write((line + self.config.line_end).encode("ascii"))
        except (serial.SerialException, OSError) as exc:
            raise DeviceError(f"cannot write to {self.name}: {exc}") from None

    def _query(self, query: str, accept: Callable[[str], bool] = bool) -> str:
        """Send `query` and return the first reply line that `accept`s; other lines (not ASCII,
        or not of the expected form) are counted as garbage and skipped."""
        with contextlib.suppress(serial.SerialException, OSError):
            self._ser.reset_input_buffer()
        self._framer.clear()
        self._write(query)
        deadline = time.monotonic() + self.config.timeout_s
        while time.monotonic() < deadline:
            try:
                chunk = self._ser.read(max(1, self._ser.in_waiting))
            except (serial.SerialException, OSError) as exc:
                raise DeviceError(f"lost connection to {self.name}: {exc}") from None
            lines, overflow = self._framer.feed(chunk)
            self.stats["garbage"] += overflow
            for raw in lines:
                try:
                    text = raw.decode("ascii").strip()
                except UnicodeDecodeError:
                    self.stats["garbage"] += 1
                    continue
                self.stats["lines"] += 1
                if accept(text):
                    return text
                self.stats["garbage"] += 1
        self.stats["timeouts"] += 1
        raise DeviceError(f"no reply from {self.name} to {query!r} within "
                          f"{self.config.timeout_s:g} s")

    def _number(self, query: str) -> float:
        """The number a query answers (lines that are not a finite number are garbage)."""
        return float(self._query(query, _is_number))


def _is_number(text: str) -> bool:
    try:
        return math.isfinite(float(text))
    except ValueError:
        return False
