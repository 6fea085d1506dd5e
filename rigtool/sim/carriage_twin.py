"""Simulated towing carriage with a rotary stage, on a pty and on TCP, moving in real time.

It speaks the serial-carriage line protocol (docs/drivers/serial-carriage.md): it accelerates
at `accel_mps2` towards the speed asked, stops before it turns to a new angle at
`turn_deg_s`, and answers `DONE <m/s> <deg>` once there (to the end that asked). Its own
watchdog stops it after `watchdog_s` without a line from the host, as a carriage
controller should. Fault switches: `stalled` (it stops changing speed and never reports
DONE) and `garbage` (a junk line before every reply). `history` records every accepted
setting; `max_abs_speed_mps` the fastest it went.
"""

from __future__ import annotations

import math
import re
import time

import numpy as np

from rigtool.sim.line_server import LineServer

_NUMBER = r"[-+]?\d+(?:\.\d*)?"
_FLOW = re.compile(rf"FLOW\s+(?P<mps>{_NUMBER})\s+(?P<deg>{_NUMBER})")


class CarriageTwin:
    """A carriage of top speed `max_speed_mps` and travel `min_deg..max_deg` of its stage."""

    def __init__(self, *, accel_mps2: float = 2.0, turn_deg_s: float = 90.0,
                 max_speed_mps: float = 3.0, min_deg: float = -90.0, max_deg: float = 90.0,
                 watchdog_s: float = 5.0, seed: int = 0, host: str = "127.0.0.1") -> None:
        self.accel_mps2, self.turn_deg_s = accel_mps2, turn_deg_s
        self.max_speed_mps, self.min_deg, self.max_deg = max_speed_mps, min_deg, max_deg
        self.watchdog_s = watchdog_s
        self.speed_mps = 0.0
        self.angle_deg = 0.0
        self.stalled = False
        self.garbage = False
        self.watchdog_trips = 0
        self.max_abs_speed_mps = 0.0
        self.history: list[tuple[str, float, float]] = []
        self._target: tuple[float, float] | None = None  # (speed, angle) heading for
        self._asker: object | None = None
        self._rng = np.random.default_rng(seed)
        self._last_rx = self._last_tick = time.monotonic()
        self._server = LineServer(self._on_line, "carriage-twin", host, tick=self._tick)
        self.pty_path, self.url = self._server.pty_path, self._server.url

    def start(self) -> CarriageTwin:
        """Start serving; returns the twin."""
        self._server.start()
        return self

    def stop(self) -> None:
        """Stop serving and close the pty and the socket."""
        self._server.stop()

    def __enter__(self) -> CarriageTwin:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def disconnect(self) -> None:
        """Fault: the controller's link vanishes (its watchdog then stops the carriage)."""
        self._server.disconnect()

    @property
    def moving(self) -> bool:
        """Whether the carriage is heading for a setting or still has speed."""
        return self._target is not None or self.speed_mps != 0

    def _send(self, end: object, text: str) -> None:
        data = text.encode("ascii") + b"\n"
        if self.garbage:
            data = bytes(self._rng.integers(0x80, 0x100, size=8, dtype=np.uint8)) + b"\n" + data
        self._server.send(end, data)

    def _on_line(self, end: object, raw: bytes) -> None:
        self._last_rx = time.monotonic()
        text = raw.decode("ascii", errors="replace").strip()
        m = _FLOW.fullmatch(text)
        if m:
            speed, angle = float(m["mps"]), float(m["deg"])
            if abs(speed) > self.max_speed_mps:
                self._send(end, f"ERR speed beyond {self.max_speed_mps:g} m/s")
            elif not self.min_deg <= angle <= self.max_deg:
                self._send(end, f"ERR angle outside {self.min_deg:g}..{self.max_deg:g} deg")
            else:
                self._target, self._asker = (speed, angle), end
                self.history.append(("FLOW", speed, angle))
                self._send(end, "OK")
        elif text == "STATE?":
            self._send(end, f"STATE {self.speed_mps:.4f} {self.angle_deg:.3f}")
        elif text == "STOP":
            self._halt(end)
            self._send(end, "OK")
        else:
            self._send(end, "ERR unknown command")

    def _halt(self, end: object | None) -> None:
        """Head for speed 0 at the present angle (STOP, or the watchdog)."""
        self.history.append(("STOP", 0.0, self.angle_deg))
        self._target = (0.0, self.angle_deg) if self.speed_mps != 0 else None
        self._asker = end

    def _tick(self) -> None:
        now = time.monotonic()
        dt, self._last_tick = now - self._last_tick, now
        if now - self._last_rx > self.watchdog_s and self.moving and self._target != (
                0.0, self.angle_deg):
            self.watchdog_trips += 1
            self._halt(None)
        if self._target is None or self.stalled:
            return
        speed, angle = self._target
        if angle != self.angle_deg:  # stop, then turn
            if self.speed_mps != 0:
                self.speed_mps = _toward(self.speed_mps, 0.0, self.accel_mps2 * dt)
            else:
                self.angle_deg = _toward(self.angle_deg, angle, self.turn_deg_s * dt)
            return
        self.speed_mps = _toward(self.speed_mps, speed, self.accel_mps2 * dt)
        self.max_abs_speed_mps = max(self.max_abs_speed_mps, abs(self.speed_mps))
        if self.speed_mps == speed:
            self._target = None
            if self._asker is not None:
                self._send(self._asker, f"DONE {self.speed_mps:.4f} {self.angle_deg:.3f}")


def _toward(x: float, target: float, step: float) -> float:
    """`x` moved by at most `step` towards `target`."""
    return target if abs(target - x) <= step else x + math.copysign(step, target - x)
