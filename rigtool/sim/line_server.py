"""A line-protocol device served on a pseudo-terminal and on TCP at once, for the twins.

`LineServer` owns the pty, the listening socket, the connected clients and one LineFramer
per end (a line is kept to at most `max_line` + 1 bytes, its tail skipped, so a stream without
line ends costs linear time and bounded memory); a twin gives it `on_line(end, raw_line)` and answers with `send(end, data)`. The
pty path and the pyserial URL (`socket://host:port`) are what a rig file names.
"""

from __future__ import annotations

import contextlib
import os
import selectors
import socket
import threading
import tty
from collections.abc import Callable

from rigtool.devices.framing import LineFramer

# bytes of one line a twin keeps; a longer line reaches `on_line` cut to MAX_LINE + 1 bytes
MAX_LINE = 4096


def open_pty() -> tuple[int, int, str]:
    """A raw pseudo-terminal: (master fd, slave fd, slave path); the master is non-blocking."""
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    return master, slave, os.ttyname(slave)


class LineServer:
    """Serve lines on a pty (`pty_path`) and on TCP (`url`) from one background thread."""

    def __init__(self, on_line: Callable[[object, bytes], None], name: str,
                 host: str = "127.0.0.1", tick: Callable[[], None] | None = None,
                 max_line: int = MAX_LINE) -> None:
        self._on_line = on_line
        self._max_line = max_line
        self._tick = tick
        self._master, self._slave, self.pty_path = open_pty()
        self._listener = socket.create_server((host, 0))  # loopback unless told otherwise
        self._listener.setblocking(False)
        self.url = f"socket://{host}:{self._listener.getsockname()[1]}"
        self._sel = selectors.DefaultSelector()
        self._sel.register(self._master, selectors.EVENT_READ, "pty")
        self._sel.register(self._listener, selectors.EVENT_READ, "listen")
        self._framers: dict[object, LineFramer] = {"pty": self._framer()}
        self._clients: list[socket.socket] = []
        self._stop = threading.Event()
        self._disconnect = threading.Event()
        self._disconnected = threading.Event()
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)

    def start(self) -> None:
        self._thread.start()

    @property
    def address(self) -> tuple[str, int]:
        """(host, port) the TCP side listens on."""
        return self._listener.getsockname()[:2]

    def stop(self) -> None:
        """Stop serving and close every endpoint. Idempotent."""
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        self._close_endpoints()

    def disconnect(self) -> None:
        """Fault: the device vanishes (pty and TCP endpoints close; the thread keeps ticking)."""
        self._disconnect.set()
        self._disconnected.wait(timeout=2.0)

    def _framer(self) -> LineFramer:
        return LineFramer(self._max_line, keep_overlong=True)

    def discard_partial_lines(self) -> None:
        """Forget every end's partial line (a firmware watchdog trip); call from `tick`."""
        for framer in self._framers.values():
            framer.clear()

    def ends(self) -> list[object]:
        """Every end a broadcast (telemetry) goes to: the pty and each TCP client."""
        return ["pty", *self._clients] if self._master >= 0 else []

    def _close_endpoints(self) -> None:
        for client in list(self._clients):
            self._drop(client)
        for obj in (self._listener, self._master):
            with contextlib.suppress(KeyError, ValueError):
                self._sel.unregister(obj)
        self._listener.close()
        for fd in (self._master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)
        self._master = self._slave = -1

    def send(self, end: object, data: bytes) -> None:
        """Write `data` to one end (what a UART or a vanished client drops is lost)."""
        with contextlib.suppress(BlockingIOError, OSError):
            if end == "pty":
                if self._master >= 0:
                    os.write(self._master, data)
            else:
                end.sendall(data)  # type: ignore[attr-defined]

    def _loop(self) -> None:
        while not self._stop.is_set():
            if self._disconnect.is_set() and not self._disconnected.is_set():
                self._close_endpoints()
                self._disconnected.set()
            if self._disconnected.is_set():
                self._stop.wait(0.01)
                continue
            for key, _ in self._sel.select(timeout=0.005):
                if key.data == "listen":
                    with contextlib.suppress(BlockingIOError):
                        client, _ = self._listener.accept()
                        client.settimeout(0.2)
                        self._clients.append(client)
                        self._sel.register(client, selectors.EVENT_READ, client)
                    continue
                try:
                    data = os.read(self._master, 4096) if key.data == "pty" else key.data.recv(4096)
                except BlockingIOError:
                    continue
                except OSError:
                    data = b""
                if not data:
                    if key.data != "pty":
                        self._drop(key.data)
                    continue
                if key.data not in self._framers:
                    self._framers[key.data] = self._framer()
                for raw in self._framers[key.data].feed(data)[0]:
                    self._on_line(key.data, raw)
            if self._tick is not None:
                self._tick()

    def _drop(self, client: socket.socket) -> None:
        with contextlib.suppress(KeyError, ValueError):
            self._sel.unregister(client)
        with contextlib.suppress(ValueError):
            self._clients.remove(client)
        self._framers.pop(client, None)
        client.close()
