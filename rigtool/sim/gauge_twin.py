"""A serial ASCII force gauge on a pseudo-terminal, fed by a LiveTwin's thrust.

The real driver (`rigtool.devices.ascii_gauge.AsciiGauge`) opens `twin.port` (the pty's
slave path) through pyserial. Personalities:

* `mark10`: answers each `?` with a line like `-18.78 lbF` (CR LF), or in `stream`
  mode prints such lines at `rate_hz`;
* `hx711-csv`: prints `millis,raw` lines at `rate_hz` (10 or 80 Hz on real boards),
  where raw = offset + force_n / scale, as an uncalibrated HX711 sketch would
  (`temperature=True`: `millis,raw,temperature_c`, a sketch that also reads a sensor).

`garbage` is the fraction of lines garbled (poll: the answer is replaced; stream: a
junk line is inserted); `silent` stops all output. Both can change while it runs.
"""

from __future__ import annotations

import contextlib
import os
import random
import select
import threading
import time
from typing import Literal

from rigtool.sim.line_server import open_pty
from rigtool.sim.live import LiveTwin
from rigtool.units import FORCE_UNITS_N, unit_factor

_JUNK = b"#$%&*@!?ABCDEFGHJKxyz \xff\x80\xfe"  # no digits: a garbled line never parses


class GaugeTwin:
    """Pty endpoint speaking a gauge preset; `port` is the path the driver opens."""

    def __init__(self, live: LiveTwin, preset: Literal["mark10", "hx711-csv"] = "mark10", *,
                 mode: Literal["poll", "stream"] | None = None, unit: str = "lbF",
                 rate_hz: float | None = None, scale: float = 0.001, offset: float = 8000.0,
                 channel: int | None = None, garbage: float = 0.0, seed: int = 0,
                 temperature: bool = False) -> None:
        if preset not in ("mark10", "hx711-csv"):
            raise ValueError(f"unknown gauge preset {preset!r}")
        self.live = live
        self.preset = preset
        self.mode = mode or ("poll" if preset == "mark10" else "stream")
        if preset == "hx711-csv" and self.mode != "stream":
            raise ValueError("the hx711-csv personality only streams")
        self.unit = unit
        self._n_per_unit = unit_factor(unit, FORCE_UNITS_N, "force")
        self.rate_hz = rate_hz or (80.0 if preset == "hx711-csv" else 10.0)
        self.scale, self.offset = scale, offset  # hx711: N per count, raw count at zero force
        self.channel = live.twin.profile.thrust_channel if channel is None else channel
        self.garbage = garbage
        self.temperature = temperature  # hx711-csv: a third field, the motor's temperature
        self.silent = False
        self.stats = dict.fromkeys(("queries", "lines", "garbage", "dropped"), 0)
        self._rng = random.Random(seed)
        self._t0 = time.monotonic()
        self._stop = threading.Event()
        self._master, self._slave, self.port = open_pty()
        self._thread = threading.Thread(target=self._loop, name="rigtool-gauge-twin", daemon=True)

    def start(self) -> GaugeTwin:
        deadline = time.monotonic() + 2.0
        while self.live.latest() is None and time.monotonic() < deadline:
            time.sleep(0.005)  # a just-started LiveTwin has no sample yet
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        for fd in (self._master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)

    def __enter__(self) -> GaugeTwin:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def rig_fields(self) -> dict:
        """What the rig's `sensor:` section needs beyond the preset: a raw HX711's scale, offset
        and unit."""
        if self.preset != "hx711-csv":
            return {}
        return {"scale": self.scale, "offset": self.offset, "unit": "N"}

    def force_n(self) -> float:
        """The force the gauge sees now: the latest LiveTwin sample on its channel (N)."""
        block = self.live.latest()
        return 0.0 if block is None else float(block.ft[-1, self.channel])

    def line(self) -> bytes:
        """One reading in this personality's format, line end included."""
        f = self.force_n()
        if self.preset == "mark10":
            return f"{f / self._n_per_unit:.2f} {self.unit}\r\n".encode()
        millis = int((time.monotonic() - self._t0) * 1000)
        raw = round(self.offset + f / self.scale)
        if self.temperature:
            return f"{millis},{raw},{self.temperature_c():.2f}\r\n".encode()
        return f"{millis},{raw}\r\n".encode()

    def temperature_c(self) -> float:
        """The motor temperature the twin reports now (NaN when its profile has none)."""
        block = self.live.latest()
        if block is None or block.temperature_c is None:
            return float("nan")
        return float(block.temperature_c[-1])

    # -- internals ------------------------------------------------------------------------
    def _junk(self) -> bytes:
        self.stats["garbage"] += 1
        return bytes(self._rng.choice(_JUNK) for _ in range(self._rng.randrange(1, 20))) + b"\r\n"

    def _write(self, data: bytes) -> None:
        if self.silent:
            return
        try:
            os.write(self._master, data)
            self.stats["lines"] += 1
        except BlockingIOError:  # nobody reads the port and its buffer is full
            self.stats["dropped"] += 1
        except OSError:
            self._stop.set()

    def _loop(self) -> None:
        period = 1.0 / self.rate_hz
        next_t = time.monotonic()
        while not self._stop.is_set():
            timeout = max(0.0, next_t - time.monotonic()) if self.mode == "stream" else 0.05
            try:
                ready, _, _ = select.select([self._master], [], [], timeout)
                data = os.read(self._master, 1024) if ready else b""
            except BlockingIOError:
                data = b""
            except OSError:
                return
            for _ in range(data.count(b"?") if self.mode == "poll" else 0):
                self.stats["queries"] += 1
                garbled = self.garbage and self._rng.random() < self.garbage
                self._write(self._junk() if garbled else self.line())
            now = time.monotonic()
            if self.mode == "stream" and now >= next_t:
                next_t = max(next_t + period, now - period)  # no burst after a stall
                if self.garbage and self._rng.random() < self.garbage:
                    self._write(self._junk())
                self._write(self.line())
