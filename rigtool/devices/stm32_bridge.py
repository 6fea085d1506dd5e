"""STM32 PWM bridge: a microcontroller timer driving a thruster, commanded over a serial line.

The bridge firmware speaks one ASCII command per line and answers every line with
`OK [value]` or `ERR <reason>` (docs/drivers/stm32-bridge.md). Command and reply
formats are configurable so an existing lab firmware can be described in the rig
file. A background thread sends the heartbeat that feeds the firmware's watchdog,
and a reader thread sorts incoming lines into replies, telemetry and garbage.
"""

from __future__ import annotations

import logging
import math
import queue
import re
import string
import threading
import time
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from rigtool.bounds import MAX_CLOCK_HZ, MAX_DURATION_S, Baudrate, Command, PositiveSeconds, Seconds
from rigtool.devices.base import ActuatorInfo, Device, FeedbackBlock
from rigtool.devices.framing import LineFramer
from rigtool.devices.thermistor import Thermistor
from rigtool.errors import DeviceError, UsageError

log = logging.getLogger(__name__)

FEEDBACK_GROUPS = ("speed_rpm", "current_a", "voltage_v", "temperature_c")
THERMISTOR_GROUP = "thermistor_counts"  # ADC counts, converted by the `thermistor:` section
_MAX_LINE = 256  # bytes; a longer run without a line end is garbage
FORMAT_FIELDS = ("channel", "value")  # the only fields a command format may name
MAX_FORMAT_WIDTH = 99  # widest field a command format may ask for
FIRMWARE_LINE = 64  # bytes of one line the bridge firmware takes (BRIDGE_MAX_LINE); longer is refused
WIDEST_FIELDS = {"channel": 99, "value": 65535}  # the widest channel and counts a line carries
# An integer's format spec: [[fill]align][sign][#][0][width][,_][type], width of 1-2 digits.
FORMAT_SPEC = re.compile(r"(?:[^{}]?[<>=^])?[+\- ]?#?0?\d{0,2}[,_]?[bdoxX]?")
_READ_TIMEOUT_S = 0.02  # reader thread poll period


class Stm32BridgeConfig(BaseModel):
    """Rig-file section for the STM32 PWM bridge (`driver: stm32-bridge`)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    driver: Literal["stm32-bridge"]
    url: str = Field(min_length=1)  # pyserial URL: /dev/ttyACM0, socket://host:port, loop://
    baudrate: Baudrate = 115200  # ignored by socket:// and loop://
    channel: int = Field(1, ge=0, le=255)  # timer channel the thruster's ESC/driver is wired to
    command_unit: Literal["pwm_counts", "pulse_us"] = "pwm_counts"  # pulse_us for an ESC
    timer_clock_hz: float = Field(72e6, ge=1, le=MAX_CLOCK_HZ)  # timer input clock (f_TIM)
    psc: int = Field(0, ge=0, le=65535)  # prescaler: tick = (psc + 1) / timer_clock_hz
    arr: int = Field(799, ge=1, le=2**32 - 1)  # auto-reload: counts 0..arr per period
    neutral: Command | None = None  # in command_unit; default 0 counts or 1500 us
    command_min: Command | None = None  # in command_unit; default 0 counts or 1100 us
    command_max: Command | None = None  # in command_unit; default arr counts or 1900 us
    timeout_s: PositiveSeconds = 0.5  # wait this long for each reply
    heartbeat_s: Seconds = 0.1  # heartbeat period; 0 = no heartbeat thread
    watchdog_ms: int = Field(500, ge=0, le=int(MAX_DURATION_S * 1000))  # firmware watchdog; 0 = firmware has none
    line_end: Literal["\n", "\r\n", "\r"] = "\n"  # appended to every command line
    # command formats ({channel}, {value} placeholders; "" = the firmware lacks it)
    set_format: str = Field("SET {channel} {value}", min_length=1)  # compare value in counts
    pulse_format: str = "PW {channel} {value}"  # pulse width in us (pulse_us mode)
    get_format: str = "GET {channel}"  # read back the compare value
    stop_format: str = "STOP"  # all channels to neutral; "" = send set_format with neutral
    heartbeat_format: str = "HB"  # feeds the watchdog
    ping_format: str = "PING"  # sent on open to check the firmware answers
    # reply patterns (full-line regexes)
    reply_regex: str = r"OK(?:\s+(?P<value>.*?))?\s*"  # success; optional group `value`
    error_regex: str = r"ERR\b\s*(?P<reason>.*?)\s*"  # refusal; optional group `reason`
    telemetry_regex: str = ""  # unsolicited feedback lines; groups named speed_rpm etc.
    thermistor: Thermistor | None = None  # converts a `thermistor_counts` telemetry group

    @field_validator("set_format", "pulse_format", "get_format", "stop_format",
                     "heartbeat_format", "ping_format")
    @classmethod
    def _format(cls, text: str) -> str:
        return command_format(text)

    @model_validator(mode="after")
    def _consistent(self) -> Stm32BridgeConfig:
        for name in ("reply_regex", "error_regex", "telemetry_regex"):
            try:
                re.compile(getattr(self, name))
            except re.error as exc:
                raise ValueError(f"{name}: invalid regex: {exc}") from None
        groups = set(re.compile(self.telemetry_regex).groupindex)
        unknown = groups - {*FEEDBACK_GROUPS, THERMISTOR_GROUP}
        if unknown:
            raise ValueError(f"telemetry_regex: unknown groups {sorted(unknown)}; "
                             f"use {', '.join((*FEEDBACK_GROUPS, THERMISTOR_GROUP))}")
        if (THERMISTOR_GROUP in groups) != (self.thermistor is not None):
            raise ValueError(f"a `{THERMISTOR_GROUP}` telemetry group and a `thermistor:` "
                             "section go together (the section converts its counts)")
        if THERMISTOR_GROUP in groups and "temperature_c" in groups:
            raise ValueError(f"telemetry_regex: give `temperature_c` or `{THERMISTOR_GROUP}`, "
                             "not both")
        info = actuator_info(self)
        if not info.command_min <= info.neutral <= info.command_max:
            raise ValueError(f"need command_min <= neutral <= command_max, got "
                             f"{info.command_min:g} <= {info.neutral:g} <= {info.command_max:g}")
        top = counts_for(self, info.command_max)
        if info.command_min < 0 or top > self.arr:
            raise ValueError(f"command range {info.command_min:g}..{info.command_max:g} "
                             f"{self.command_unit} does not fit the timer (0..{self.arr} counts, "
                             f"period {period_us(self):g} us); adjust psc/arr")
        if self.heartbeat_s and self.watchdog_ms and self.heartbeat_s > self.watchdog_ms / 2000:
            raise ValueError(f"heartbeat_s {self.heartbeat_s:g} must be at most half the "
                             f"firmware watchdog ({self.watchdog_ms} ms)")
        return self


def command_format(text: str) -> str:
    """`text` if it is a command format rigtool can fill: literal text and the fields
    {channel} and {value}, each with at most an integer format spec of width up to
    MAX_FORMAT_WIDTH; a ValueError saying what else it holds. A format string from a file
    is parsed, never tried: attributes, indexes and conversions are refused unread."""
    try:
        parts = list(string.Formatter().parse(text))
    except ValueError as exc:
        raise ValueError(f"not a format string ({exc}); write {{{{ and }}}} for braces") from None
    for _, field, spec, conversion in parts:
        if field is None:
            continue
        if field not in FORMAT_FIELDS or conversion is not None:
            shown = (field + (f"!{conversion}" if conversion is not None else ""))[:40]
            raise ValueError(f"{{{shown}}}: only {{channel}} and {{value}} may appear")
        if spec and not FORMAT_SPEC.fullmatch(spec):
            raise ValueError(f"{{{field}:{spec[:40]}}}: only an integer format (fill, align, sign, "
                             f"width up to {MAX_FORMAT_WIDTH}, type b/d/o/x/X) may follow a field")
    if not all(" " <= c <= "~" for c in text):
        bad = next(c for c in text if not " " <= c <= "~")
        raise ValueError(f"holds {bad!r}: a command is one line of printable ASCII (a line end "
                         "or control character would send another command)")
    try:
        widest = max(len(text.format(channel=1, value=0)), len(text.format(**WIDEST_FIELDS)))
    except ValueError as exc:
        raise ValueError(f"{text!r}: {exc}") from None
    if widest > FIRMWARE_LINE:
        raise ValueError(f"its lines reach {widest} bytes; the bridge firmware takes at most "
                         f"{FIRMWARE_LINE}")
    return text


def tick_s(config: Stm32BridgeConfig) -> float:
    """Duration of one timer count."""
    return (config.psc + 1) / config.timer_clock_hz


def period_us(config: Stm32BridgeConfig) -> float:
    """PWM period: f_PWM = f_TIM / ((PSC+1)(ARR+1))."""
    return (config.arr + 1) * tick_s(config) * 1e6


def counts_for(config: Stm32BridgeConfig, value: float) -> int:
    """Compare value (CCR) for a command in the config's unit."""
    if config.command_unit == "pwm_counts":
        return round(value)
    return round(value * 1e-6 / tick_s(config))


def pulse_us_for(config: Stm32BridgeConfig, counts: float) -> float:
    """Pulse width of a compare value."""
    return counts * tick_s(config) * 1e6


def actuator_info(config: Stm32BridgeConfig) -> ActuatorInfo:
    """The command space the engine sees, with unit-dependent defaults filled in."""
    counts = config.command_unit == "pwm_counts"
    neutral = config.neutral if config.neutral is not None else (0.0 if counts else 1500.0)
    lo = config.command_min if config.command_min is not None else (0.0 if counts else 1100.0)
    hi = config.command_max if config.command_max is not None else (
        float(config.arr) if counts else 1900.0)
    groups = set(re.compile(config.telemetry_regex).groupindex)
    if THERMISTOR_GROUP in groups:
        groups.add("temperature_c")
    feedback = tuple(g for g in FEEDBACK_GROUPS if g in groups)
    return ActuatorInfo(config.command_unit, float(neutral), float(lo), float(hi), feedback)


class _WriteFailed(DeviceError):
    """Nothing reached the port (as opposed to a missing or refused reply)."""


class Stm32Bridge(Device):
    """Actuator driver for the STM32 PWM bridge over any pyserial URL."""

    info_for = staticmethod(actuator_info)  # the command space from a config alone (registry)

    def __init__(self, config: Stm32BridgeConfig) -> None:
        import serial
        self.config = config
        self.info = actuator_info(config)
        self.name = f"STM32 bridge on {config.url}"
        self.stats = dict.fromkeys(("frames", "replies", "errors", "garbage", "timeouts", "late",
                                    "heartbeats", "heartbeat_failures", "telemetry"), 0)
        self.version: str | None = None
        self.command = self.info.neutral
        self._ok = re.compile(config.reply_regex)
        self._err = re.compile(config.error_regex)
        self._tel = re.compile(config.telemetry_regex) if config.telemetry_regex else None
        self._replies: queue.Queue[tuple[str, str | None]] = queue.Queue()
        self._feedback: list[tuple[float, dict[str, float]]] = []
        self._fb_lock = threading.Lock()
        self._tx_lock = threading.Lock()
        self._stop = threading.Event()
        self._lost: str | None = None
        try:
            self._ser = serial.serial_for_url(config.url, baudrate=config.baudrate,
                                              timeout=_READ_TIMEOUT_S, write_timeout=config.timeout_s)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise DeviceError(f"cannot open {config.url} (STM32 bridge): {exc}") from None
        self._reader = threading.Thread(target=self._read_loop, name="stm32-bridge-rx", daemon=True)
        self._reader.start()
        self._heart: threading.Thread | None = None
        try:
            if config.ping_format:
                self.version = self._transact(config.ping_format.format(channel=config.channel,
                                                                        value=0))
        except DeviceError:
            self._release()  # nothing was commanded yet: no neutral to send
            raise
        if config.heartbeat_s > 0 and config.heartbeat_format:
            self._heart = threading.Thread(target=self._heartbeat_loop, name="stm32-bridge-hb",
                                           daemon=True)
            self._heart.start()

    # -- Actuator -------------------------------------------------------------------------
    def set_command(self, value: float) -> None:
        """Command `value` in info.command_unit (validated against the range and the timer)."""
        info = self.info
        if not math.isfinite(value) or not info.command_min <= value <= info.command_max:
            raise UsageError(f"command {value!r} {info.command_unit} outside "
                             f"{info.command_min:g}..{info.command_max:g} for {self.name}")
        self._transact(self._command_line(value))
        self.command = float(value)

    def neutral(self) -> None:
        """Stop (or set neutral); DeviceError unless the firmware acknowledged one of them."""
        if self._closed:
            return
        cfg = self.config
        lines = [self._command_line(self.info.neutral)]
        if cfg.stop_format:
            lines.insert(0, cfg.stop_format.format(channel=cfg.channel, value=0))
        problems = []
        for line in lines:
            try:
                self._transact(line)
            except _WriteFailed:
                raise
            except DeviceError as exc:
                problems.append(str(exc))
                continue
            self.command = self.info.neutral
            return
        raise DeviceError(f"neutral not acknowledged by {self.name}: {'; '.join(problems)}")

    def read_feedback(self) -> FeedbackBlock:
        """Telemetry lines received since the last call (none unless telemetry_regex is set)."""
        with self._fb_lock:
            rows, self._feedback = self._feedback, []
        t = np.array([r[0] for r in rows], dtype=float)
        fields = {g: np.array([r[1].get(g, np.nan) for r in rows], dtype=float)
                  for g in self.info.feedback}
        return FeedbackBlock(t, **fields)

    def _safe_state(self) -> None:
        """Neutral before `close` releases the port; a failure is logged, not raised."""
        try:
            self.neutral()
        except DeviceError as exc:
            log.warning("could not command neutral on close of %s: %s", self.name, exc)

    # -- extras ---------------------------------------------------------------------------
    def read_back(self) -> int:
        """The compare value (counts) the firmware has in force on the configured channel."""
        cfg = self.config
        if not cfg.get_format:
            raise DeviceError(f"{self.name}: no get_format configured")
        line = cfg.get_format.format(channel=cfg.channel, value=0)
        value = self._transact(line)
        try:
            return round(float(value or ""))
        except ValueError:
            raise DeviceError(f"{self.name}: reply to {line!r} carries no number: {value!r}") from None

    # -- internals ------------------------------------------------------------------------
    def _command_line(self, value: float) -> str:
        cfg = self.config
        if cfg.command_unit == "pulse_us" and cfg.pulse_format:
            return cfg.pulse_format.format(channel=cfg.channel, value=round(value))
        return cfg.set_format.format(channel=cfg.channel, value=counts_for(cfg, value))

    def _transact(self, line: str) -> str | None:
        """Send one line and wait for its reply; return the reply's `value` group."""
        import serial
        with self._tx_lock:
            if self._closed:
                raise _WriteFailed(f"{self.name} is closed")
            if self._lost is not None:
                raise _WriteFailed(f"lost connection to {self.name}: {self._lost}")
            while True:
                try:
                    self._replies.get_nowait()
                except queue.Empty:
                    break
                self.stats["late"] += 1
            try:
                self._ser.write((line + self.config.line_end).encode("ascii"))
            except (serial.SerialException, OSError) as exc:
                raise _WriteFailed(f"cannot write to {self.name}: {exc}") from None
            try:
                kind, payload = self._replies.get(timeout=self.config.timeout_s)
            except queue.Empty:
                self.stats["timeouts"] += 1
                raise DeviceError(f"no reply from {self.name} to {line!r} within "
                                  f"{self.config.timeout_s:g} s") from None
        if kind == "lost":
            raise DeviceError(f"lost connection to {self.name}: {payload}")
        if kind == "err":
            raise DeviceError(f"{self.name} refused {line!r}: {payload or 'ERR'}")
        return payload

    def _heartbeat_loop(self) -> None:
        cfg = self.config
        line = cfg.heartbeat_format.format(channel=cfg.channel, value=0)
        while not self._stop.wait(cfg.heartbeat_s):
            try:
                self._transact(line)
                self.stats["heartbeats"] += 1
            except DeviceError as exc:
                self.stats["heartbeat_failures"] += 1
                log.debug("heartbeat to %s failed: %s", self.name, exc)

    def _read_loop(self) -> None:
        import serial
        framer = LineFramer(_MAX_LINE)
        while not self._stop.is_set():
            try:
                chunk = self._ser.read(max(1, self._ser.in_waiting))
            except (serial.SerialException, OSError) as exc:
                if not self._stop.is_set():
                    self._lost = str(exc) or type(exc).__name__
                    self._replies.put(("lost", self._lost))
                return
            lines, overflow = framer.feed(chunk)
            for raw in lines:
                self._handle_line(raw)
            if overflow:
                self.stats["garbage"] += 1

    def _handle_line(self, raw: bytes) -> None:
        t = time.monotonic()
        try:
            text = raw.decode("ascii").strip()
        except UnicodeDecodeError:
            self.stats["garbage"] += 1
            return
        if not text:
            return
        if self._tel is not None and (m := self._tel.fullmatch(text)):
            try:
                values = {k: float(v) for k, v in m.groupdict().items() if v is not None}
            except ValueError:
                self.stats["garbage"] += 1
                return
            if THERMISTOR_GROUP in values and self.config.thermistor is not None:
                counts = values.pop(THERMISTOR_GROUP)
                values["temperature_c"] = float(self.config.thermistor.temperature_c(counts))
            with self._fb_lock:
                self._feedback.append((t, values))
            self.stats["frames"] += 1
            self.stats["telemetry"] += 1
        elif m := self._ok.fullmatch(text):
            self.stats["frames"] += 1
            self.stats["replies"] += 1
            self._replies.put(("ok", m.groupdict().get("value")))
        elif m := self._err.fullmatch(text):
            self.stats["frames"] += 1
            self.stats["errors"] += 1
            self._replies.put(("err", m.groupdict().get("reason") or text))
        else:
            self.stats["garbage"] += 1

    def _release(self) -> None:
        """Stop the heartbeat and the reader, close the port."""
        import serial
        self._stop.set()
        for thread in (self._heart, self._reader):
            if thread is not None and thread is not threading.current_thread():
                thread.join(timeout=2.0)
        try:
            self._ser.close()
        except (serial.SerialException, OSError) as exc:
            log.debug("closing %s: %s", self.name, exc)
