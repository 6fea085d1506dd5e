"""Simulated STM32 PWM bridge firmware, on a pseudo-terminal and a TCP socket at once.

It speaks the bridge line protocol (docs/drivers/stm32-bridge.md) or any dialect
described by a `Dialect`, keeps a compare value (CCR) per timer channel, applies
the thruster channel to a LiveTwin, and runs the firmware watchdog: when no line
arrives for `watchdog_ms` every channel goes to neutral, a partial line is discarded and the
trip is recorded. `PW` converts microseconds with the firmware's integer rule (pulse_to_ccr).
Fault switches: `garbage` (a junk line before every reply), `no_replies` (commands
are applied but never answered) and `disconnect()` (the device vanishes).
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass

import numpy as np

from rigtool.devices.thermistor import Thermistor
from rigtool.sim.line_server import LineServer
from rigtool.sim.live import LiveTwin

_PLACEHOLDERS = {"{channel}": r"(?P<channel>\d+)", "{value}": r"(?P<value>[-+]?\d+)"}  # integers
MAX_LINE = 64  # bytes between line ends, as in the firmware; a longer line is refused whole


@dataclass(frozen=True)
class Dialect:
    """How the firmware spells commands and replies (defaults: the rigtool bridge protocol)."""

    set: str = "SET {channel} {value}"
    pulse: str = "PW {channel} {value}"
    get: str = "GET {channel}"
    stop: str = "STOP"
    heartbeat: str = "HB"
    ping: str = "PING"
    ok: str = "OK"
    ok_value: str = "OK {value}"
    error: str = "ERR {reason}"
    version: str = "rigtool-bridge 1.0"
    telemetry: str = "TEL {speed_rpm:.1f} {current_a:.3f} {voltage_v:.2f}"


def pulse_to_ccr(us: int, timer_clock_hz: int, psc: int) -> int:
    """Compare value for a pulse of `us` microseconds, as the firmware computes it (doc: PW):
    us * f_TIM / (10^6 (PSC+1)) in exact integers, rounded to the nearest count, ties to even."""
    q, r = divmod(us * timer_clock_hz, 1_000_000 * (psc + 1))
    den = 1_000_000 * (psc + 1)
    return q + (1 if 2 * r > den or (2 * r == den and q % 2) else 0)


def command_pattern(fmt: str) -> re.Pattern[str]:
    """Regex that parses lines written with the format string `fmt`."""
    parts = re.split(r"(\{channel\}|\{value\})", fmt)
    return re.compile("".join(_PLACEHOLDERS.get(p, re.escape(p)) for p in parts))



class Stm32BridgeTwin:
    """The bridge firmware on a pty (`pty_path`) and on TCP (`url`), driving a LiveTwin."""

    def __init__(
        self,
        live: LiveTwin,
        *,
        channels: int = 4,
        thruster_channel: int = 1,
        timer_clock_hz: float = 72e6,  # a whole number of Hz, as the firmware's uint32
        psc: int | None = None,
        arr: int | None = None,
        ccr_range: tuple[int, int] | None = None,
        watchdog_ms: int = 500,
        dialect: Dialect | None = None,
        telemetry_hz: float = 0.0,
        thermistor: Thermistor | None = None,
        seed: int = 0,
        host: str = "127.0.0.1",
    ) -> None:
        profile = live.twin.profile
        self.live = live
        self.pulse_unit = profile.command_unit == "pulse_us"
        # counts profile: the source rig's timer; pulse profile: 1 us ticks at 50 Hz
        self.psc = psc if psc is not None else (71 if self.pulse_unit else 0)
        self.arr = arr if arr is not None else (19999 if self.pulse_unit else 799)
        if timer_clock_hz != int(timer_clock_hz):
            raise ValueError(f"timer_clock_hz {timer_clock_hz} is not a whole number of Hz")
        self.timer_clock_hz = int(timer_clock_hz)
        self.tick_us = (self.psc + 1) / timer_clock_hz * 1e6
        # the compare values the output can put out (the Arduino Servo build: 544..2400)
        self.ccr_range = ccr_range or (0, self.arr)
        self.neutral_ccr = round(profile.neutral / self.tick_us if self.pulse_unit else profile.neutral)
        self.channels = range(1, channels + 1)
        self.thruster_channel = thruster_channel
        self.watchdog_ms = watchdog_ms
        self.dialect = dialect or Dialect()
        self.telemetry_hz = telemetry_hz
        self.thermistor = thermistor  # telemetry's {thermistor_counts}: the motor's temperature
        self.ccr = dict.fromkeys(self.channels, self.neutral_ccr)
        self.garbage = False
        self.no_replies = False
        self.watchdog_trips: list[float] = []
        self.lines_received = 0
        self.bad_lines = 0
        self._rng = np.random.default_rng(seed)
        d = self.dialect
        self._patterns = [(kind, command_pattern(fmt)) for kind, fmt in (
            ("set", d.set), ("pulse", d.pulse), ("get", d.get), ("stop", d.stop),
            ("heartbeat", d.heartbeat), ("ping", d.ping)) if fmt]  # fmt: skip
        self._last_line_t = time.monotonic()
        self._armed = False
        self._next_tel = 0.0
        self._server = LineServer(self._on_line, "stm32-bridge-twin", host, tick=self._tick,
                                  max_line=MAX_LINE)
        self.pty_path, self.url = self._server.pty_path, self._server.url
        self.port = int(self.url.rsplit(":", 1)[1])

    def start(self) -> Stm32BridgeTwin:
        self.live.set_command(self._live_command(self.ccr[self.thruster_channel]))
        self._server.start()
        return self

    def stop(self) -> None:
        self._server.stop()

    @property
    def address(self) -> tuple[str, int]:
        """(host, port) the TCP side listens on."""
        return self._server.address

    def disconnect(self) -> None:
        """Fault: the device vanishes (pty and TCP endpoints close)."""
        self._server.disconnect()

    def __enter__(self) -> Stm32BridgeTwin:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- firmware -------------------------------------------------------------------------
    def _live_command(self, ccr: int) -> float:
        return ccr * self.tick_us if self.pulse_unit else float(ccr)

    def _apply(self, channel: int, ccr: int) -> None:
        self.ccr[channel] = ccr
        if channel == self.thruster_channel:
            self.live.set_command(self._live_command(ccr))

    def _all_neutral(self) -> None:
        for ch in self.channels:
            self._apply(ch, self.neutral_ccr)

    def _reply(self, text: str) -> str:
        """Execute one host line and return the firmware's answer."""
        d = self.dialect
        parsed = next(((kind, m) for kind, rx in self._patterns if (m := rx.fullmatch(text))), None)
        if parsed is None:
            self.bad_lines += 1
            return d.error.format(reason="unknown command")
        kind, groups = parsed[0], parsed[1].groupdict()
        channel = int(groups["channel"]) if "channel" in groups else self.thruster_channel
        if channel not in self.channels:
            return d.error.format(reason=f"no channel {channel}")
        if kind in ("set", "pulse"):
            value = int(groups["value"])
            ccr = abs(value) if kind == "pulse" else value
            if kind == "pulse":
                ccr = pulse_to_ccr(ccr, self.timer_clock_hz, self.psc) * (-1 if value < 0 else 1)
            low, high = self.ccr_range
            if not low <= ccr <= high:
                return d.error.format(reason=f"out of range {low}..{high}")
            self._apply(channel, ccr)
            return d.ok_value.format(value=ccr)
        if kind == "get":
            return d.ok_value.format(value=self.ccr[channel])
        if kind == "stop":
            self._all_neutral()
            return d.ok
        if kind == "ping":
            return d.ok_value.format(value=d.version)
        return d.ok

    def _watchdog(self, now: float) -> None:
        if self.watchdog_ms and self._armed and now - self._last_line_t > self.watchdog_ms / 1000:
            self._all_neutral()
            self._server.discard_partial_lines()  # a line cut off by the trip never runs
            self.watchdog_trips.append(now)
            self._armed = False

    # -- transport ------------------------------------------------------------------------
    def _send(self, end: object, text: str) -> None:
        data = text.encode("ascii") + b"\n"
        if self.garbage:
            data = bytes(self._rng.integers(0x80, 0x100, size=8, dtype=np.uint8)) + b"\n" + data
        self._server.send(end, data)

    def _on_line(self, end: object, raw: bytes) -> None:
        self.lines_received += 1
        self._last_line_t = time.monotonic()
        self._armed = True
        if len(raw) > MAX_LINE:
            self.bad_lines += 1
            answer = self.dialect.error.format(reason="line too long")
        else:
            answer = self._decode_and_reply(raw)
        if not self.no_replies:
            self._send(end, answer)

    def _decode_and_reply(self, raw: bytes) -> str:
        try:
            return self._reply(raw.decode("ascii").strip())
        except UnicodeDecodeError:
            self.bad_lines += 1
            return self.dialect.error.format(reason="bad line")

    def _tick(self) -> None:
        now = time.monotonic()
        self._watchdog(now)
        self._telemetry(now)

    def _telemetry(self, now: float) -> None:
        if self.telemetry_hz <= 0 or now < self._next_tel:
            return
        self._next_tel = now + 1.0 / self.telemetry_hz
        block = self.live.latest()
        if block is None:
            return
        temperature = (float(block.temperature_c[-1]) if block.temperature_c is not None
                       else float("nan"))
        counts = self.thermistor.counts(temperature) if self.thermistor is not None else 0
        text = self.dialect.telemetry.format(speed_rpm=float(block.speed_rpm[-1]),
                                             current_a=float(block.current_a[-1]),
                                             voltage_v=float(block.voltage_v[-1]),
                                             temperature_c=temperature, thermistor_counts=counts)
        for end in self._server.ends():
            self._send(end, text)
