"""Single-axis force gauges and load-cell amplifiers that talk ASCII lines over a serial port.

Two ways to get readings:

* `poll`: send a query (Mark-10: `?` + CR) and take the line that comes back;
* `stream`: the device prints lines on its own (an HX711 behind a microcontroller
  printing `millis,value` at 10 or 80 Hz, or a gauge in continuous-output mode).

Each line must match a regular expression (matched against the whole line, surrounding
blanks removed) with a named group `value`, and optionally `unit` (N, kN, kgf, gf,
lbf, ozf, ... case-insensitive, so Mark-10's `lbF` works), `seq` (a device counter
or millisecond timestamp, returned as the block's `seq`) and `temperature_c` (an auxiliary
temperature, for the protocol's `max_temperature_c`; not stored). Lines that do not match are
counted and skipped. The reading in N is `sign * (value - offset) * scale * unit`;
it goes on the configured F/T channel and the other five channels are NaN.
"""

from __future__ import annotations

import contextlib
import logging
import re
import threading
import time
from collections.abc import Callable, Mapping
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import ConfigDict, Field, model_validator

from rigtool.bounds import Baudrate, PositiveSeconds, Scale
from rigtool.devices.base import Device, ForceBlock
from rigtool.devices.buffer import SampleBuffer
from rigtool.devices.capabilities import SensorSection
from rigtool.devices.framing import LineFramer
from rigtool.errors import DeviceError
from rigtool.units import FORCE_UNITS_N, FT_CHANNELS, unit_factor

log = logging.getLogger(__name__)

_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_MAX_LINE = 256  # bytes; a longer run without a line end is garbage
_READ_TIMEOUT_S = 0.05

PRESETS: dict[str, dict[str, Any]] = {
    # Mark-10 (and similar) gauges: "-18.78 lbF", polled with "?" + CR.
    "mark10": {"mode": "poll", "query": "?\r",
               "pattern": rf"(?P<value>{_NUMBER})\s*(?P<unit>[A-Za-z]+)?"},
    # A microcontroller reading an HX711: "millis,raw_or_grams" per line at 10 or 80 Hz.
    "hx711-csv": {"mode": "stream",
                  "pattern": rf"(?P<seq>\d+)\s*[,;]\s*(?P<value>{_NUMBER})", "unit": "N"},
}


class AsciiGaugeConfig(SensorSection):
    """The `sensor:` section of a rig file for a serial ASCII force gauge (one force axis)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    driver: Literal["ascii-gauge"]
    url: str = Field(min_length=1)  # pyserial URL: /dev/ttyUSB0, socket://host:port, a pty
    baudrate: Baudrate = 9600
    preset: Literal["mark10", "hx711-csv"] | None = None  # fills mode, query, pattern, unit
    mode: Literal["poll", "stream"] | None = None
    query: str | None = None  # poll: sent for every reading (YAML "?\r" is ? + CR)
    pattern: str | None = None  # regex with a named group `value` (optional `unit`, `seq`)
    unit: str | None = None  # unit of `value` when the line has no `unit` group or it is empty
    scale: Scale = 1.0  # e.g. N per count for a raw HX711 value (with unit: N)
    offset: Scale = 0.0  # subtracted from `value` before scaling (e.g. the raw zero)
    channel: Literal["fx", "fy", "fz"] = "fx"  # F/T channel the gauge's axis maps to
    sign: Literal[1, -1] = 1
    timeout_s: PositiveSeconds = 1.0  # reply timeout (poll); longest silence (stream)
    max_failures: Annotated[int, Field(ge=1, le=1_000_000)] = 5  # poll: consecutive queries without a reading before a fault
    max_gap_s: PositiveSeconds = 0.25  # stream: pause between reads after which old lines are dropped

    @model_validator(mode="before")
    @classmethod
    def _preset_defaults(cls, data: Any) -> Any:
        if isinstance(data, Mapping) and data.get("preset") in PRESETS:
            return {**PRESETS[data["preset"]], **data}
        return data

    @model_validator(mode="after")
    def _consistent(self) -> AsciiGaugeConfig:
        if self.mode is None:
            raise ValueError("give `mode: poll` or `mode: stream` (or a preset)")
        if self.mode == "poll" and not self.query:
            raise ValueError("mode poll needs a `query` to send (e.g. \"?\\r\")")
        if not self.pattern:
            raise ValueError("give a `pattern` with a named group `value` (or a preset)")
        try:
            groups = re.compile(self.pattern).groupindex
        except re.error as exc:
            raise ValueError(f"pattern is not a valid regular expression: {exc}") from None
        if "value" not in groups:
            raise ValueError("pattern needs a named group `value`, e.g. (?P<value>[-+]?\\d+\\.?\\d*)")
        if self.unit is not None:
            unit_factor(self.unit, FORCE_UNITS_N, "force")
        elif "unit" not in groups:
            raise ValueError("the pattern has no `unit` group: give the `unit` of the value")
        if self.scale == 0 or not np.isfinite(self.scale) or not np.isfinite(self.offset):
            raise ValueError("scale must be finite and non-zero, offset finite")
        return self

    def temperature_source(self) -> bool:
        """A gauge reads a temperature when its pattern has a `temperature_c` group."""
        return has_temperature(self)


def has_temperature(config: AsciiGaugeConfig) -> bool:
    """Whether the gauge's lines carry a `temperature_c` field (an auxiliary channel)."""
    return "temperature_c" in re.compile(config.pattern or "").groupindex


class LineParser:
    """One line of text -> (seq or None, reading in N before bias), or None if it does not match."""

    def __init__(self, config: AsciiGaugeConfig) -> None:
        self.config = config
        self._pattern = re.compile(config.pattern or "")

    def __call__(self, text: str) -> tuple[int | None, float] | None:
        parsed = self.fields(text)
        return None if parsed is None else parsed[:2]

    def fields(self, text: str) -> tuple[int | None, float, float] | None:
        """(seq or None, reading in N, temperature_c or NaN), or None if the line does not match."""
        cfg = self.config
        m = self._pattern.fullmatch(text.strip())
        if m is None:
            return None
        groups = m.groupdict()
        try:
            temperature = float(groups.get("temperature_c") or "nan")
        except ValueError:
            temperature = float("nan")
        unit = groups.get("unit") or cfg.unit
        try:
            value = float(groups["value"])
            factor = unit_factor(unit, FORCE_UNITS_N, "force") if unit else None
            seq = int(groups["seq"]) if groups.get("seq") else None
        except (TypeError, ValueError):
            return None
        if factor is None or not np.isfinite(value):
            return None
        return seq, cfg.sign * (value - cfg.offset) * cfg.scale * factor, temperature


class AsciiGauge(Device):
    """ForceSensor for a serial ASCII gauge: one axis, on `config.channel`, in N."""

    channels = FT_CHANNELS

    def __init__(self, config: AsciiGaugeConfig | Mapping, *,
                 now: Callable[[], float] = time.monotonic) -> None:
        import serial
        cfg = config if isinstance(config, AsciiGaugeConfig) else AsciiGaugeConfig.model_validate(config)
        self.config = cfg
        self.name = f"force gauge on {cfg.url}"
        self._now = now
        self.parse = LineParser(cfg)
        self.has_temperature = has_temperature(cfg)
        self._query = (cfg.query or "").encode("ascii")
        self._channel = FT_CHANNELS.index(cfg.channel)
        self._bias = 0.0
        self._count = 0  # running sequence for lines without a `seq` group
        self._stats = dict.fromkeys(("lines", "readings", "unparseable", "timeouts", "queries"), 0)
        self._buffer = SampleBuffer(100_000)
        self._stop = threading.Event()
        try:
            self._ser = serial.serial_for_url(cfg.url, baudrate=cfg.baudrate,
                                              timeout=_READ_TIMEOUT_S, write_timeout=cfg.timeout_s)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise DeviceError(f"cannot open {cfg.url} ({self.name}): {exc}") from None
        self._thread = threading.Thread(target=self._read_loop, name="rigtool-gauge", daemon=True)
        self._thread.start()
        try:
            self.read(1, 10.0)  # fail now, naming the port, rather than mid-sweep
        except BaseException:
            self.close()
            raise

    # -- ForceSensor ----------------------------------------------------------------------
    def read(self, n: int, rate_hz: float) -> ForceBlock:
        """`n` readings. Poll mode queries at most `rate_hz` times a second (slower if the
        device answers slower); stream mode returns the next `n` lines at the device's rate."""
        if self._closed:
            raise DeviceError(f"{self.name}: read after close")
        if n <= 0:
            return ForceBlock(np.empty(0), np.empty((0, 6)), np.empty(0, dtype=np.int64))
        rows = self._poll(n, rate_hz) if self.config.mode == "poll" else self._stream(n)
        arr = np.asarray(rows, dtype=float)
        ft = np.full((n, 6), np.nan)
        ft[:, self._channel] = arr[:, 2] - self._bias
        temperature = arr[:, 3] if self.has_temperature else None
        return ForceBlock(arr[:, 0], ft, arr[:, 1].astype(np.int64), temperature)

    def set_bias(self, bias: np.ndarray) -> None:
        """Subtract the bias of this gauge's channel from later readings (on top of earlier ones)."""
        b = np.asarray(bias, dtype=float).reshape(-1)
        value = b[self._channel] if b.shape == (6,) else np.nan
        if not np.isfinite(value):
            raise ValueError(f"{self.name}: bias needs a number for channel {self.config.channel}, "
                             f"got {bias!r}")
        self._bias += float(value)

    def _release(self) -> None:
        """Stop the reader thread and release the port (on `close`)."""
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=1.0)
        with contextlib.suppress(Exception):
            self._ser.close()

    @property
    def stats(self) -> dict:
        """Counters since open: lines, readings, unparseable, timeouts, queries, stale."""
        return {**self._stats, "stale": self._buffer.stale, "overflowed": self._buffer.overflowed}

    # -- internals ------------------------------------------------------------------------
    def _poll(self, n: int, rate_hz: float) -> list[tuple]:
        import serial
        cfg = self.config
        rows: list[tuple] = []
        failures = 0
        t0 = self._now()
        while len(rows) < n:
            wait = t0 + len(rows) / rate_hz - self._now() if rate_hz > 0 else 0.0
            if wait > 0:
                time.sleep(wait)
            self._buffer.clear()  # a late reply to an earlier query must not answer this one
            try:
                self._ser.write(self._query)
            except (serial.SerialException, OSError) as exc:
                raise DeviceError(f"{self.name}: cannot send the query: {exc}") from None
            self._stats["queries"] += 1
            got = self._buffer.take(1, cfg.timeout_s)
            if got and np.isfinite(got[0][2]):
                rows.extend(got)
                failures = 0
                continue
            failures += 1  # no answer, or an answer that does not parse: ask again
            if not got:
                self._stats["timeouts"] += 1
            if failures >= cfg.max_failures:
                raise DeviceError(
                    f"{self.name}: no valid reading in answer to {cfg.query!r} for {failures} "
                    f"queries in a row ({self._stats['timeouts']} timeouts of {cfg.timeout_s:g} s, "
                    f"{self._stats['unparseable']} unparseable lines so far). Check url, baudrate "
                    "and pattern")
        return rows

    def _stream(self, n: int) -> list[tuple]:
        cfg = self.config
        self._buffer.begin_read(self._now(), cfg.max_gap_s)
        rows: list[tuple] = []
        while len(rows) < n:
            got = self._buffer.take(n - len(rows), cfg.timeout_s)
            if not got:
                raise DeviceError(
                    f"{self.name}: no valid reading for {cfg.timeout_s:g} s ({len(rows)} of {n} "
                    f"read; {self._stats['lines']} lines received, {self._stats['unparseable']} "
                    "unparseable). Check url, baudrate and pattern")
            rows.extend(got)
        self._buffer.end_read(self._now())
        return rows

    def _read_loop(self) -> None:
        import serial
        framer = LineFramer(_MAX_LINE)
        while not self._stop.is_set():
            try:
                chunk = self._ser.read(max(1, self._ser.in_waiting))
            except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
                if not self._stop.is_set():
                    self._buffer.fail(DeviceError(f"{self.name}: port lost: {exc}"))
                return
            if not chunk:
                continue
            t = self._now()
            lines, overflow = framer.feed(chunk)
            rows = [self._line(raw, t) for raw in lines if raw.strip()]
            if self.config.mode == "stream":
                rows = [row for row in rows if np.isfinite(row[2])]
            if rows:
                self._buffer.put_many(rows)
            if overflow:
                self._stats["lines"] += 1
                self._stats["unparseable"] += 1

    def _line(self, raw: bytes, t: float) -> tuple:
        """(t, seq, reading in N); the reading is NaN for a line that does not parse."""
        self._stats["lines"] += 1
        parsed = self.parse.fields(raw.decode("ascii", errors="replace"))
        if parsed is None:
            self._stats["unparseable"] += 1
            return t, -1, np.nan, np.nan
        seq, value, temperature = parsed
        self._count += 1
        self._stats["readings"] += 1
        return t, self._count if seq is None else seq, value, temperature
