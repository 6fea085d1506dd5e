"""Line framing for the serial personalities and drivers: one place that splits a byte stream
into CR- or LF-terminated lines."""

from __future__ import annotations

import re

_EOL = re.compile(rb"[\r\n]")


class LineFramer:
    """Accumulates bytes and hands back complete, non-empty lines (without their CR/LF).

    A partial line longer than `max_line` bytes (None: no limit) is dropped, and `feed`
    reports it, so a stream of garbage without line ends cannot grow the buffer.
    """

    def __init__(self, max_line: int | None = None) -> None:
        self.max_line = max_line
        self._buf = b""

    def clear(self) -> None:
        """Forget a partial line (e.g. before a request whose reply must be fresh)."""
        self._buf = b""

    def feed(self, data: bytes) -> tuple[list[bytes], bool]:
        """(complete lines, whether an overlong partial line was dropped) after `data`."""
        *lines, self._buf = _EOL.split(self._buf + data)
        overflow = self.max_line is not None and len(self._buf) > self.max_line
        if overflow:
            self._buf = b""
        return [line for line in lines if line], overflow
