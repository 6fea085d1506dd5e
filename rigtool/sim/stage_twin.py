"""Simulated motorised truss stage on a pseudo-terminal, moving in real time.

It speaks the serial-stage line protocol (docs/drivers/serial-stage.md), moves at
`speed_mm_s` towards its target and keeps the LiveTwin's depth in step with its
position. Fault switches: `stalled` (the carriage stops moving and never reports
DONE) and `garbage` (a junk line before every reply).
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import selectors
import threading
import time

import numpy as np

from rigtool.devices.framing import LineFramer
from rigtool.sim.line_server import open_pty
from rigtool.sim.live import LiveTwin

_MOVE = re.compile(r"MOVE\s+(?P<mm>[-+]?\d+(?:\.\d*)?)")
_STEP_S = 0.005  # position update period


class StageTwin:
    """A linear stage on `pty_path`: travel `min_mm..max_mm`, depth = direction*(pos - zero)."""

    def __init__(
        self,
        live: LiveTwin | None = None,
        *,
        speed_mm_s: float = 50.0,
        position_mm: float = 0.0,
        min_mm: float = 0.0,
        max_mm: float = 1500.0,
        zero_offset_m: float = 0.0,
        direction: int = 1,
        seed: int = 0,
    ) -> None:
        self.live = live
        self.speed_mm_s = speed_mm_s
        self.position_mm = float(position_mm)
        self.target_mm: float | None = None  # None: not moving
        self.min_mm, self.max_mm = min_mm, max_mm
        self.zero_offset_m = zero_offset_m
        self.direction = direction
        self.stalled = False
        self.garbage = False
        self.lines_received = 0
        self._rng = np.random.default_rng(seed)
        self._master, self._slave, self.pty_path = open_pty()
        self._framer = LineFramer()
        self._sel = selectors.DefaultSelector()
        self._sel.register(self._master, selectors.EVENT_READ)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="stage-twin", daemon=True)

    def depth_m(self) -> float:
        """Propeller-centre depth at the current position."""
        return self.direction * (self.position_mm / 1000.0 - self.zero_offset_m)

    def start(self) -> StageTwin:
        if self.live is not None:
            self.live.set_depth(self.depth_m())
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        self._sel.close()
        for fd in (self._master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)

    def __enter__(self) -> StageTwin:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _send(self, text: str) -> None:
        data = text.encode("ascii") + b"\n"
        if self.garbage:
            data = bytes(self._rng.integers(0x80, 0x100, size=8, dtype=np.uint8)) + b"\n" + data
        with contextlib.suppress(OSError):
            os.write(self._master, data)

    def _command(self, text: str) -> None:
        """Execute one host line, replying on the pty."""
        m = _MOVE.fullmatch(text)
        if m:
            target = float(m["mm"])
            if not self.min_mm <= target <= self.max_mm:
                self._send(f"ERR out of travel {self.min_mm:g}..{self.max_mm:g} mm")
                return
            self.target_mm = target
            self._send("OK")
        elif text == "HOME":
            self.target_mm = self.min_mm
            self._send("OK")
        elif text == "POS?":
            self._send(f"POS {self.position_mm:.3f}")
        elif text == "STOP":
            moving = self.target_mm is not None
            self.target_mm = None
            self._send("OK")
            if moving:
                self._send(f"DONE {self.position_mm:.3f}")
        else:
            self._send("ERR unknown command")

    def _advance(self, dt: float) -> None:
        if self.target_mm is None or self.stalled:
            return
        gap = self.target_mm - self.position_mm
        step = self.speed_mm_s * dt
        self.position_mm = self.target_mm if abs(gap) <= step else self.position_mm + math.copysign(step, gap)
        if self.live is not None:
            self.live.set_depth(self.depth_m())
        if self.position_mm == self.target_mm:
            self.target_mm = None
            self._send(f"DONE {self.position_mm:.3f}")

    def _loop(self) -> None:
        last = time.monotonic()
        while not self._stop.is_set():
            data = b""
            for _ in self._sel.select(timeout=_STEP_S):
                with contextlib.suppress(BlockingIOError, OSError):
                    data += os.read(self._master, 4096)
            for raw in self._framer.feed(data)[0]:
                self.lines_received += 1
                self._command(raw.decode("ascii", errors="replace").strip())
            now = time.monotonic()
            self._advance(now - last)
            last = now
