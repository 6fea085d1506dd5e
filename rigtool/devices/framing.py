"""Line framing for the serial personalities and drivers: one place that splits a byte stream
into CR- or LF-terminated lines, in time linear in the bytes fed."""

from __future__ import annotations

import re

_EOL = re.compile(rb"[\r\n]")


class LineFramer:
    """Accumulates bytes and hands back complete, non-empty lines (without their CR/LF).

    A partial line longer than `max_line` bytes (None: no limit) is dropped, and `feed`
    reports it, so a stream of garbage without line ends cannot grow the buffer. With
    `keep_overlong` (a device refusing a long line whole, as the bridge firmware does) the
    line is kept instead, cut to `max_line + 1` bytes, its tail skipped up to its line end,
    and handed back then, so the caller sees it was too long.
    """

    def __init__(self, max_line: int | None = None, *, keep_overlong: bool = False) -> None:
        if keep_overlong and max_line is None:
            raise ValueError("keep_overlong needs a max_line")
        self.max_line = max_line
        self.keep_overlong = keep_overlong
        self._buf = bytearray()

    def clear(self) -> None:
        """Forget a partial line (e.g. before a request whose reply must be fresh)."""
        self._buf.clear()

    def feed(self, data: bytes) -> tuple[list[bytes], bool]:
        """(complete lines, whether an overlong partial line was dropped) after `data`."""
        parts = _EOL.split(data)
        if self.keep_overlong:
            return self._feed_keeping(parts), False
        lines: list[bytes] = []
        if len(parts) == 1:
            self._buf += data
        else:
            lines = [bytes(self._buf) + parts[0], *parts[1:-1]]
            self._buf = bytearray(parts[-1])
        overflow = self.max_line is not None and len(self._buf) > self.max_line
        if overflow:
            self._buf.clear()
        return [line for line in lines if line], overflow

    def _feed_keeping(self, parts: list[bytes]) -> list[bytes]:
        """Lines of at most `max_line + 1` bytes: an overlong line keeps only its head."""
        assert self.max_line is not None
        lines = []
        for i, part in enumerate(parts):
            room = self.max_line + 1 - len(self._buf)
            if room > 0:
                self._buf += part[:room]
            if i < len(parts) - 1:
                if self._buf:
                    lines.append(bytes(self._buf))
                self._buf.clear()
        return lines
