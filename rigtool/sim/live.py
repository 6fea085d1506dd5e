"""The physics twin running in real time, shared by the device personalities of `rigtool sim`.

One background thread advances the twin in small blocks at a fixed rate and hands
every block to the subscribers (e.g. the Net F/T personality streams it over UDP, a
CAN driver personality reports the latest speed). Commands and depth changes from
any thread are applied at the current time, under one lock, so the twin always sees
non-decreasing times.
"""

from __future__ import annotations

import contextlib
import queue
import threading
import time
from dataclasses import dataclass

import numpy as np

from rigtool.sim.physics import ThrusterTwin


@dataclass
class LiveBlock:
    """Samples of one physics step: times on the live clock plus the twin's outputs."""

    t_s: np.ndarray
    ft: np.ndarray
    speed_rpm: np.ndarray
    current_a: np.ndarray
    voltage_v: np.ndarray
    temperature_c: np.ndarray | None = None


class LiveTwin:
    """Runs a ThrusterTwin on the monotonic clock at `rate_hz`, in blocks of `block_s`."""

    def __init__(self, twin: ThrusterTwin, rate_hz: float = 1000.0, block_s: float = 0.01) -> None:
        self.twin = twin
        self.rate_hz = rate_hz
        self.block_s = block_s
        self._lock = threading.Lock()
        self._t0 = time.monotonic() - twin.t_s
        self._next_t = twin.t_s
        self._subscribers: list[queue.Queue] = []
        self._latest: LiveBlock | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="rigtool-live-twin", daemon=True)

    def now(self) -> float:
        """Seconds on the twin's time axis."""
        return time.monotonic() - self._t0

    def start(self) -> LiveTwin:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)

    def subscribe(self, maxsize: int = 1000) -> queue.Queue:
        """A queue that receives every LiveBlock from now on (oldest dropped if it fills)."""
        q: queue.Queue = queue.Queue(maxsize=maxsize)
        with self._lock:
            self._subscribers.append(q)
        return q

    def set_command(self, command: float) -> None:
        """Generate the samples due so far under the old command, then apply the new one."""
        with self._lock:
            self._step_locked()
            self.twin.set_command(max(self._next_t, self.twin.t_s), command)

    def set_depth(self, depth_m: float) -> None:
        with self._lock:
            self._step_locked()
            self.twin.set_depth(max(self._next_t, self.twin.t_s), depth_m)

    @property
    def command(self) -> float:
        return self.twin.command

    def latest(self) -> LiveBlock | None:
        """The most recent block (feedback telemetry reads its last values)."""
        return self._latest

    def _step(self) -> None:
        with self._lock:
            self._step_locked()

    def _step_locked(self) -> None:
        """Sample every instant from the last generated one up to now and publish the block."""
        n = int((self.now() - self._next_t) * self.rate_hz)
        if n <= 0:
            return
        start = max(self._next_t, self.twin.t_s)
        t = start + np.arange(n) / self.rate_hz
        out = self.twin.sample(t)
        self._next_t = float(t[-1]) + 1.0 / self.rate_hz
        block = LiveBlock(t, out.ft, out.speed_rpm, out.current_a, out.voltage_v,
                          out.temperature_c)
        self._latest = block
        for q in self._subscribers:
            try:
                q.put_nowait(block)
            except queue.Full:
                with contextlib.suppress(queue.Empty, queue.Full):
                    q.get_nowait()
                    q.put_nowait(block)

    def _loop(self) -> None:
        while not self._stop.is_set():
            self._step()
            self._stop.wait(self.block_s)
