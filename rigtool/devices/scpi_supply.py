"""Programmable bench power supply over SCPI (Keysight E36xx/N67xx, Rigol DP8xx, R&S HMP,
Korad in SCPI mode): the supply-voltage axis of a sweep (docs/drivers/scpi-supply.md).

Talks over any pyserial URL: a serial port, or `socket://host:port` for a LAN supply's raw
SCPI socket (port 5025 on most); or, with the optional `visa` extra, over a VISA resource
(`resource: TCPIP::host::5025::SOCKET`, USBTMC, VXI-11, serial) through pyvisa (visa_link.py). Opening the supply only asks (identity, output state,
setpoints, which protections it has) and commands nothing, unless its output is already on
outside the rig's limits, which is switched off at once. Every setting is confirmed: after
`VOLT`, `CURR` or `OUTP` the driver reads `SYST:ERR?` and the setting back. An output is only
switched on after the current limit, the over-voltage protection (where the supply has one)
and a setpoint within the rig's limits have been programmed with the output off and read back;
voltage changes are then ramped at `slew_v_per_s`. `safe()` (and `close()`) turns the output
off or ramps it to `safe_voltage_v` as the rig file asks, and never switches an output on.
Where the supply has an output watchdog (`OUTP:PROT:WDOG`), it is armed, so the output goes
off by itself when the host stops talking (kill -9); a keep-alive thread talks meanwhile. Lines
that are not ASCII or not a number where one is expected are counted as garbage and skipped.
"""

from __future__ import annotations

import contextlib
import math
import re
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated, ClassVar, Literal

from pydantic import ConfigDict, Field, field_validator, model_validator

from rigtool.bounds import Baudrate, PositiveSeconds
from rigtool.config import FieldError
from rigtool.devices.base import Device
from rigtool.devices.capabilities import SupplySection
from rigtool.devices.framing import LineFramer
from rigtool.devices.visa_link import VisaLink, check_library, check_resource, looks_like_resource
from rigtool.errors import DeviceError, UsageError

_MAX_LINE = 256
_ERROR_REPLY = re.compile(r"[+-]?\d+,")  # SYST:ERR? answers `code,"message"`
_RAMP_STEP_S = 0.05  # a ramp sends a new setpoint this often
_STATES = {"1": True, "0": False, "ON": True, "OFF": False}
Volts = Annotated[float, Field(ge=0, le=1000, allow_inf_nan=False)]
Amps = Annotated[float, Field(gt=0, le=1000, allow_inf_nan=False)]
Protection = Literal["auto", "required", "off"]


class ScpiSupplyConfig(SupplySection):
    """Rig-file section for an SCPI supply (`driver: scpi-supply`); it measures its terminals."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    measures_supply: ClassVar[bool] = True
    driver: Literal["scpi-supply"]
    url: str | None = Field(None, min_length=1)  # pyserial URL: /dev/ttyUSB0, socket://host:5025
    # or a VISA resource string (needs the `visa` extra): TCPIP::host::5025::SOCKET, USB0::...::INSTR
    resource: str | None = Field(None, min_length=1)
    # pyvisa backend: @py, @ivi (the system's VISA), @sim, x.yaml@sim (relative: to the rig file)
    visa_library: str = Field("@py", min_length=1, max_length=4096)
    baudrate: Baudrate = 9600  # serial ports only
    timeout_s: PositiveSeconds = 1.0  # reply timeout
    max_voltage_v: Volts = 60.0  # refuse setpoints above this (the thruster's rating)
    current_limit_a: Amps = 10.0  # the supply's current limit (from the protocol's limits)
    slew_v_per_s: Annotated[float, Field(gt=0, le=1000, allow_inf_nan=False)] = 10.0
    on_exit: Literal["off", "safe_voltage"] = "off"  # what safe() leaves the output at
    safe_voltage_v: Volts = 0.0
    line_end: Literal["\n", "\r\n"] = "\n"
    over_voltage_protection: Protection = "auto"  # VOLT:PROT at max_voltage_v where it exists
    watchdog: Protection = "auto"  # OUTP:PROT:WDOG: output off when the host goes silent
    watchdog_s: Annotated[float, Field(ge=1, le=3600, allow_inf_nan=False)] = 10.0
    # a setting reads back within this (V or A) or 0.1 %: a supply's setpoint resolution
    readback_tolerance: Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)] = 0.011

    @field_validator("resource")
    @classmethod
    def _visa_resource(cls, value: str | None) -> str | None:
        return None if value is None else check_resource(value)

    @field_validator("visa_library")
    @classmethod
    def _visa_backend(cls, value: str) -> str:
        return check_library(value)

    @model_validator(mode="after")
    def _one_link(self) -> ScpiSupplyConfig:
        if self.url is not None and looks_like_resource(self.url):
            raise FieldError(("url",), f"{self.url!r} is a VISA resource string: give it as "
                             "`resource:` (opened through pyvisa, the `visa` extra)")
        if (self.url is None) == (self.resource is None):
            raise ValueError("give the supply's link as either `url:` (pyserial) or "
                             "`resource:` (VISA), exactly one of them")
        return self

    @property
    def where(self) -> str:
        """The link in messages: the pyserial URL or the VISA resource string."""
        return self.resource or self.url or ""

    @model_validator(mode="after")
    def _safe_voltage_within_limit(self) -> ScpiSupplyConfig:
        if self.safe_voltage_v > self.max_voltage_v:
            raise ValueError(f"safe_voltage_v ({self.safe_voltage_v:g} V) is above "
                             f"max_voltage_v ({self.max_voltage_v:g} V)")
        return self


@dataclass(frozen=True)
class SupplyState:
    """What the supply was doing when it was opened (a shared bench keeps its last settings)."""

    output_on: bool
    setpoint_v: float
    current_limit_a: float
    ovp_v: float | None  # the over-voltage protection level; None: the supply has none


@dataclass(frozen=True)
class SupplyProtection:
    """Which protections the supply answered for when it was opened."""

    over_voltage: bool  # answers VOLT:PROT?
    watchdog: bool  # answers OUTP:PROT:WDOG?


class ScpiSupply(Device):
    """A supply the engine sets the bus voltage with; `measure()` reads it back."""

    reached_by = "supply"

    def __init__(self, config: ScpiSupplyConfig) -> None:
        self.config = config
        self.name = f"SCPI supply on {config.where}"
        self.stats = dict.fromkeys(("lines", "garbage", "timeouts", "errors"), 0)
        self._framer = LineFramer(_MAX_LINE)
        self._lock = threading.RLock()  # the port, between the caller and the keep-alive
        self._keepalive_stop = threading.Event()
        self._keepalive: threading.Thread | None = None
        self._last_io = time.monotonic()
        self._armed = False  # limits, protection and a safe setpoint programmed this session
        self._watchdog_armed = False
        self._ovp_set = False
        self._link = _open_link(config)
        try:
            self.identity = self._query("*IDN?")
            self._output_on = self._state("OUTP?")
            self._setpoint_v = self._number("VOLT?")
            self.found = SupplyState(self._output_on, self._setpoint_v, self._number("CURR?"),
                                     self._probe("VOLT:PROT?"))
            self.protection = SupplyProtection(self.found.ovp_v is not None,
                                               self._probe("OUTP:PROT:WDOG?") is not None)
            self._check_found_state()
            self._require_protection()
        except BaseException:
            self._release()
            raise

    # -- what the engine uses -----------------------------------------------------------------
    def set_voltage(self, volts: float) -> float:
        """Bring the output to `volts` and return the voltage measured there. The first call
        switches an output found on off, arms it (current limit, 0 V setpoint, protection, each
        read back) and only then switches it on; the setpoint is ramped at the slew limit."""
        self._check_setpoint(volts)
        with self._lock:
            if not self._armed:
                if self._output_on:  # found on: settings are only ever programmed while off
                    self.output(False)
                self._arm()
            if not self._output_on:
                self.output(True)
            self._ramp(volts)
            return self.measure()[0]

    def output(self, on: bool) -> None:
        """Switch the output on or off (confirmed). On only once armed, at a setpoint within
        the limits read back from the supply."""
        with self._lock:
            if on:
                if not self._armed:
                    raise DeviceError(f"{self.name}: output on refused: limits not programmed")
                setpoint = self._number("VOLT?")
                if not 0.0 <= setpoint <= self.config.max_voltage_v:
                    raise DeviceError(f"{self.name}: output on refused: its setpoint reads "
                                      f"{setpoint:g} V, outside 0..{self.config.max_voltage_v:g}"
                                      " V (max_voltage_v)")
            self._write(f"OUTP {'ON' if on else 'OFF'}")
            self._check_error(f"OUTP {'ON' if on else 'OFF'}")
            if self._state("OUTP?") != on:
                raise DeviceError(f"{self.name}: OUTP? does not read {'ON' if on else 'OFF'} "
                                  "after setting it")
            self._output_on = on
            if on:
                self._start_keepalive()

    def measure(self) -> tuple[float, float]:
        """(volts, amps) the supply measures at its output."""
        with self._lock:
            return self._number("MEAS:VOLT?"), self._number("MEAS:CURR?")

    @property
    def current_limit_a(self) -> float:
        """The current limit programmed (constant-current mode begins there)."""
        return self.config.current_limit_a

    def is_on(self) -> bool:
        """Whether the output is on, as the supply says now."""
        with self._lock:
            self._output_on = self._state("OUTP?")
            return self._output_on

    def safe(self) -> None:
        """Output off; with `on_exit: safe_voltage`, a supply that was found on (something else
        relies on it) is instead ramped down to safe_voltage_v, never up. Never switches an
        output on. Idempotent, quiet after close. DeviceError when the supply does not confirm."""
        if self._closed:
            return
        with self._lock:
            keep_on = self.config.on_exit == "safe_voltage" and self.found.output_on
            if keep_on and self.is_on():
                self._ramp(min(self.config.safe_voltage_v, self._setpoint_v))
            else:
                self.output(False)

    def _safe_state(self) -> None:
        """On `close`: safe state if this session programmed the supply; the watchdog disarmed
        and the over-voltage level found restored (a bench supply goes back to its next user as
        it was). A failure here is raised once `close` has released the port."""
        if self._armed:  # a supply this session never programmed is left as it was found
            self.safe()
        if self._watchdog_armed:
            self._set("OUTP:PROT:WDOG OFF", "OUTP:PROT:WDOG?", 0.0)
        if self._ovp_set and self.found.ovp_v is not None and not self._output_on:
            self._set(f"VOLT:PROT {self.found.ovp_v:.4f}", "VOLT:PROT?", self.found.ovp_v)

    # -- internals ----------------------------------------------------------------------------
    def _check_setpoint(self, volts: float) -> None:
        if not (math.isfinite(volts) and 0.0 <= volts <= self.config.max_voltage_v):
            raise UsageError(f"setpoint {volts!r} V is outside 0..{self.config.max_voltage_v:g} V "
                             f"(max_voltage_v of {self.name})")

    def _check_found_state(self) -> None:
        """An output found on above the rig's limit is switched off at once, and reported."""
        if self._output_on and self._setpoint_v > self.config.max_voltage_v:
            self.output(False)
            raise DeviceError(f"{self.name}: its output was on at a {self._setpoint_v:g} V "
                              f"setpoint, above max_voltage_v ({self.config.max_voltage_v:g} V) "
                              "of the rig file; switched it off")

    def _require_protection(self) -> None:
        for kind, have in (("over_voltage_protection", self.protection.over_voltage),
                           ("watchdog", self.protection.watchdog)):
            if getattr(self.config, kind) == "required" and not have:
                raise DeviceError(f"{self.name} ({self.identity}) has no {kind.replace('_', ' ')}"
                                  f" (`{kind}: required` in the rig file)")

    def _arm(self) -> None:
        """With the output off: the current limit, a 0 V setpoint, then the over-voltage
        protection (a supply may refuse one below its setpoint) and the watchdog, each read
        back."""
        if self._output_on:
            raise DeviceError(f"{self.name}: settings are only programmed with the output off")
        cfg = self.config
        self._set(f"CURR {cfg.current_limit_a:.4f}", "CURR?", cfg.current_limit_a)
        self._set("VOLT 0.0000", "VOLT?", 0.0)
        self._setpoint_v = 0.0
        if self.protection.over_voltage and cfg.over_voltage_protection != "off":
            self._set(f"VOLT:PROT {cfg.max_voltage_v:.4f}", "VOLT:PROT?", cfg.max_voltage_v)
            self._ovp_set = True
        if self.protection.watchdog and cfg.watchdog != "off":
            self._set(f"OUTP:PROT:WDOG:DEL {cfg.watchdog_s:.3f}", "OUTP:PROT:WDOG:DEL?",
                      cfg.watchdog_s)
            self._set("OUTP:PROT:WDOG ON", "OUTP:PROT:WDOG?", 1.0)
            self._watchdog_armed = True
        self._armed = True

    def _ramp(self, volts: float) -> None:
        """Move the setpoint to `volts` in slew-limited steps, each confirmed."""
        self._check_setpoint(volts)
        start = self._setpoint_v
        steps = max(1, math.ceil(abs(volts - start) / self.config.slew_v_per_s / _RAMP_STEP_S))
        t0 = time.monotonic()
        for k in range(1, steps + 1):
            target = start + (volts - start) * k / steps
            self._set(f"VOLT {target:.4f}", "VOLT?", target)
            self._setpoint_v = target
            if k < steps:
                time.sleep(max(0.0, t0 + k * _RAMP_STEP_S - time.monotonic()))

    def _start_keepalive(self) -> None:
        """Talk to an armed watchdog often enough that only a dead host lets it fire."""
        if self._keepalive is not None or not (self.protection.watchdog
                                                and self.config.watchdog != "off"):
            return
        self._keepalive = threading.Thread(target=self._keep_alive, daemon=True,
                                           name="scpi-supply-keepalive")
        self._keepalive.start()

    def _keep_alive(self) -> None:
        period = self.config.watchdog_s / 4
        while not self._keepalive_stop.wait(period / 4):
            if time.monotonic() - self._last_io < period:
                continue
            with self._lock:
                if self._closed:
                    return
                with contextlib.suppress(DeviceError):
                    self._state("OUTP?")

    def _release(self) -> None:
        self._keepalive_stop.set()
        with self._lock:
            self._closed = True
            with contextlib.suppress(OSError):
                self._link.close()

    def _probe(self, query: str) -> float | None:
        """What the supply answers to `query`, or None when it does not know it (it stays
        silent for `timeout_s`, or queues an error)."""
        try:
            value: float | None = self._number(query)
        except DeviceError:
            self.stats["timeouts"] -= 1  # a probe, not a fault of the link
            value = None
        error = self._query("SYST:ERR?", _ERROR_REPLY.match)
        return value if error.startswith(("0,", "+0,")) else None

    def _set(self, command: str, query: str, expect: float) -> None:
        """Send a setting, then check the error queue and the value read back."""
        self._write(command)
        self._check_error(command)
        got = self._number(query)
        if abs(got - expect) > max(self.config.readback_tolerance, 1e-3 * abs(expect)):
            raise DeviceError(f"{self.name}: {query} reads {got:g} after {command!r}")

    def _check_error(self, command: str) -> None:
        """The error queue must be empty after `command`."""
        error = self._query("SYST:ERR?", _ERROR_REPLY.match)
        if not error.startswith(("0,", "+0,")):
            self.stats["errors"] += 1
            raise DeviceError(f"{self.name} refused {command!r}: {error}")

    def _state(self, query: str) -> bool:
        """An on/off state: `1`/`0` (Keysight, R&S) or `ON`/`OFF` (Rigol)."""
        return _STATES[self._query(query, lambda text: text.upper() in _STATES).upper()]

    def _write(self, line: str) -> None:
        if self._closed:
            raise DeviceError(f"{self.name} is closed")
        try:
            self._link.write((line + self.config.line_end).encode("ascii"))
        except OSError as exc:
            raise DeviceError(f"cannot write to {self.name}: {exc}") from None
        self._last_io = time.monotonic()

    def _query(self, query: str, accept: Callable[[str], bool] = bool) -> str:
        """Send `query` and return the first reply line that `accept`s; other lines (not ASCII,
        or not of the expected form) are counted as garbage and skipped."""
        with self._lock:
            with contextlib.suppress(OSError):
                self._link.discard_input()
            self._framer.clear()
            self._write(query)
            deadline = time.monotonic() + self.config.timeout_s
            while time.monotonic() < deadline:
                try:
                    chunk = self._link.read(_MAX_LINE, deadline - time.monotonic())
                except OSError as exc:
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


class _SerialLink:
    """A pyserial port or URL as the driver's byte link (reads poll every 20 ms)."""

    def __init__(self, url: str, baudrate: int, timeout_s: float) -> None:
        import serial
        try:
            self._ser = serial.serial_for_url(url, baudrate=baudrate, timeout=0.02,
                                              write_timeout=timeout_s)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise DeviceError(f"cannot open {url} (SCPI supply): {exc}") from None

    def write(self, data: bytes) -> None:
        self._ser.write(data)

    def read(self, max_bytes: int, timeout_s: float) -> bytes:
        """What has arrived (at least one byte is waited for, 20 ms at most)."""
        return self._ser.read(min(max_bytes, max(1, self._ser.in_waiting)))

    def discard_input(self) -> None:
        self._ser.reset_input_buffer()

    def close(self) -> None:
        self._ser.close()


def _open_link(config: ScpiSupplyConfig) -> _SerialLink | VisaLink:
    """The supply's byte link: pyserial for `url:`, pyvisa (imported only then) for `resource:`."""
    if config.resource is None:
        return _SerialLink(config.url or "", config.baudrate, config.timeout_s)
    return VisaLink(config.resource, config.visa_library, config.baudrate, config.timeout_s)


def _is_number(text: str) -> bool:
    try:
        return math.isfinite(float(text))
    except ValueError:
        return False
