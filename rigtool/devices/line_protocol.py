"""What the ASCII line-protocol drivers share (the serial stage, the serial carriage): the
port opened from a pyserial URL, one request and its reply, the lines read, and the counts of
garbage, unexpected replies, refusals and timeouts. Each driver gives its reply pattern."""

from __future__ import annotations

import contextlib
import re
import time

from rigtool.devices.base import Device
from rigtool.devices.framing import LineFramer
from rigtool.errors import DeviceError

MAX_LINE = 256  # bytes; a longer run without a line end is garbage


class ReplyTimeout(DeviceError):
    """The device did not answer in time."""


class LineProtocolDevice(Device):
    """A device answering `KIND [argument]` lines; `ERR <reason>` is a refusal."""

    line_pattern: re.Pattern[str]  # groups `kind` and `arg`

    def _open_port(self, url: str, baudrate: int, timeout_s: float, what: str) -> None:
        """Open the port; DeviceError naming the URL when it cannot be opened."""
        import serial
        self.stats = dict.fromkeys(("lines", "garbage", "unexpected", "errors", "timeouts"), 0)
        self._framer = LineFramer(MAX_LINE)
        self._pending: list[str] = []
        self._reply_timeout_s = timeout_s
        try:
            self._ser = serial.serial_for_url(url, baudrate=baudrate, timeout=0.02,
                                              write_timeout=timeout_s)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise DeviceError(f"cannot open {url} ({what}): {exc}") from None

    def _release(self) -> None:
        """Release the port (on `close`)."""
        import serial
        with contextlib.suppress(serial.SerialException, OSError):
            self._ser.close()

    def _request(self, line: str, kind: str) -> str | None:
        """Send `line` and return the argument of the first `kind` reply."""
        import serial
        if self._closed:
            raise DeviceError(f"{self.name} is closed")
        try:
            self._ser.reset_input_buffer()  # a stale reply must not answer this request
            self._framer.clear()
            self._pending.clear()
            self._ser.write(f"{line}\n".encode("ascii"))
        except (serial.SerialException, OSError) as exc:
            raise DeviceError(f"cannot write to {self.name}: {exc}") from None
        return self._expect(kind, self._reply_timeout_s, line)

    def _expect(self, kind: str, budget_s: float, what: str) -> str | None:
        """Read lines until one of `kind` (ERR raises); ReplyTimeout after `budget_s`."""
        deadline = time.monotonic() + budget_s
        while time.monotonic() < deadline:
            if not self._pending:
                self._pending = self._lines()
            while self._pending:
                m = self.line_pattern.fullmatch(self._pending.pop(0))
                if m is None:
                    self.stats["garbage"] += 1
                elif m["kind"] == "ERR":
                    self.stats["errors"] += 1
                    raise DeviceError(f"{self.name} refused {what!r}: {m['arg'] or 'ERR'}")
                elif m["kind"] == kind:
                    return m["arg"]
                else:
                    self.stats["unexpected"] += 1
        self.stats["timeouts"] += 1
        raise ReplyTimeout(f"no {kind} reply from {self.name} to {what!r} within {budget_s:.3g} s")

    def _lines(self) -> list[str]:
        """Complete lines read within one poll period (undecodable ones counted as garbage)."""
        import serial
        try:
            chunk = self._ser.read(max(1, self._ser.in_waiting))
        except (serial.SerialException, OSError) as exc:
            raise DeviceError(f"lost connection to {self.name}: {exc}") from None
        parts, overflow = self._framer.feed(chunk)
        self.stats["garbage"] += int(overflow)
        out = []
        for raw in parts:
            try:
                out.append(raw.decode("ascii").strip())
            except UnicodeDecodeError:
                self.stats["garbage"] += 1
                continue
            self.stats["lines"] += 1
        return out
