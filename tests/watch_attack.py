"""A hostile local client of a watch page, run as its own process (`python -m
tests.watch_attack PORT SECONDS SEED`): slowloris, a /data flood and a battery of raw
malformed requests at once, until SECONDS have passed. Seeded; used by test_watch_attack.py."""

from __future__ import annotations

import contextlib
import random
import socket
import sys
import threading
import time

BATTERY = (b"GET /../../etc/passwd HTTP/1.1\r\nHost: localhost\r\n\r\n",
           b"GET / HTTP/9x\r\n\r\n", b"BREW / HTTP/1.1\r\n\r\n", b"GET / HTTP/1.1\r\n\r\n",
           b"GET /" + b"a" * 70_000 + b" HTTP/1.1\r\n\r\n",
           b"GET / HTTP/1.1\r\n" + b"X-Pad: y\r\n" * 200 + b"\r\n",
           b"GET /data HTTP/1.1\r\nHost: localhost\r\nContent-Length: 5\r\n"
           b"Transfer-Encoding: chunked\r\n\r\n0\r\n\r\n")
SLOW_CONNECTIONS = 300


def _connect(port: int) -> socket.socket | None:
    try:
        return socket.create_connection(("127.0.0.1", port), timeout=2)
    except OSError:
        return None


def slowloris(port: int, stop: threading.Event) -> None:
    """Hold up to SLOW_CONNECTIONS connections open, each sending a header line now and then."""
    held: list[socket.socket] = []
    while not stop.is_set():
        held = [s for s in held if s.fileno() >= 0]
        if len(held) < SLOW_CONNECTIONS and (s := _connect(port)) is not None:
            with contextlib.suppress(OSError):
                s.sendall(b"GET /data HTTP/1.1\r\nHost: localhost\r\n")
                held.append(s)
            continue
        for s in held:
            try:
                s.sendall(b"X-Slow: 1\r\n")
            except OSError:
                s.close()
        time.sleep(0.5)


def request(port: int, stop: threading.Event, rng: random.Random, raw: bool) -> None:
    """Send /data requests (or random battery requests) back to back, reading each answer."""
    while not stop.is_set():
        s = _connect(port)
        if s is None:
            time.sleep(0.01)
            continue
        with contextlib.suppress(OSError), s:
            s.sendall(rng.choice(BATTERY) if raw else
                      b"GET /data HTTP/1.1\r\nHost: localhost\r\n\r\n")
            while s.recv(65536):
                pass


def main() -> None:
    port, seconds, seed = int(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3])
    stop = threading.Event()
    workers = [threading.Thread(target=slowloris, args=(port, stop), daemon=True)]
    workers += [threading.Thread(target=request, args=(port, stop, random.Random(seed + k), k >= 6),
                                 daemon=True) for k in range(8)]
    for worker in workers:
        worker.start()
    time.sleep(seconds)
    stop.set()


if __name__ == "__main__":
    main()
