"""A thread-safe FIFO between a driver's reader thread and its `read()`.

Streaming devices (the Net F/T over UDP, an ASCII gauge that prints lines on its own)
deliver samples whether or not the engine is reading. A reader thread stamps each
sample with its arrival time and puts it here; `read()` takes the next ones. Reads that
follow each other closely get a contiguous stream. After a pause longer than the
driver's `max_gap_s`, what arrived in the pause is dropped, so readings taken while the
engine ramped a command or moved the truss are never passed off as settle or
acquisition data (the in-process simulator behaves the same way). Samples that arrived in
the pause but reach the buffer only after the read began (a reader thread that takes its
socket's queue every few milliseconds) are dropped too: their arrival time gives them away.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Iterable


class SampleBuffer:
    """Bounded FIFO of tuples whose first element is the arrival time (monotonic s)."""

    def __init__(self, max_samples: int) -> None:
        self._items: deque[tuple] = deque()
        self._max = max_samples
        self._cond = threading.Condition()
        self._error: BaseException | None = None
        self.overflowed = 0  # oldest samples discarded because nobody read them in time
        self.stale = 0  # samples dropped because they arrived during a pause between reads
        self._read_end: float | None = None
        self._floor = float("-inf")  # samples that arrived before this belong to a pause

    def __len__(self) -> int:
        return len(self._items)

    def put_many(self, items: Iterable[tuple]) -> None:
        with self._cond:
            floor = self._floor
            if floor > float("-inf"):
                items = list(items)
                kept = [item for item in items if item[0] >= floor]
                self.stale += len(items) - len(kept)
                items = kept
            self._items.extend(items)
            excess = len(self._items) - self._max
            for _ in range(max(0, excess)):
                self._items.popleft()
            self.overflowed += max(0, excess)
            self._cond.notify_all()

    def fail(self, error: BaseException) -> None:
        """The reader thread died: every later `take` raises `error`."""
        with self._cond:
            self._error = error
            self._cond.notify_all()

    def clear(self) -> None:
        with self._cond:
            self._items.clear()

    def begin_read(self, now: float, max_gap_s: float) -> None:
        """Start a read at `now`: after a pause longer than `max_gap_s`, drop what came meanwhile."""
        if self._read_end is not None and now - self._read_end <= max_gap_s:
            return
        with self._cond:
            self._floor = now
            while self._items and self._items[0][0] < now:
                self._items.popleft()
                self.stale += 1

    def end_read(self, now: float) -> None:
        self._read_end = now

    def take(self, n: int, timeout_s: float) -> list[tuple]:
        """Up to `n` samples, waiting until `n` are there or nothing new comes for `timeout_s`."""
        out: list[tuple] = []
        with self._cond:
            while True:
                if self._error is not None:
                    raise self._error
                k = min(n - len(out), len(self._items))
                out.extend(self._items.popleft() for _ in range(k))
                if len(out) >= n or not self._cond.wait(timeout_s):
                    return out
