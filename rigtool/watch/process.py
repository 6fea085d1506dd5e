"""The watch page beside a sweep, served by a separate process so that no client of the page
shares the sweep's interpreter, threads or priority.

The sweep binds the listening socket itself (its address is known, and a taken port is
named, before anything starts) and hands it to `python -m rigtool.watch.process`, which
serves the latest run read-only from the database at a lower priority (WATCH_NICE). The
child ends when its standard input closes: when the sweep stops it, or when the sweep
process dies in any way, kill -9 included.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import socket
import subprocess
import sys
import threading
from pathlib import Path

from rigtool.watch.server import WatchServer, listening_socket

WATCH_NICE = 10  # the server runs this much nicer than the sweep
STOP_WAIT_S = 5.0


class WatchProcess:
    """A watch server in a child process following the latest run of `db`; `stop` ends it."""

    def __init__(self, db: Path, port: int, bind: str) -> None:
        """Bind bind:port (RigtoolError when taken or refused) and start the child on it."""
        listener = listening_socket(bind, port)
        host, bound = listener.getsockname()[:2]
        host = f"[{host}]" if ":" in str(host) else host
        self.url = f"http://{host}:{bound}/"
        try:
            self._proc = subprocess.Popen(
                [sys.executable, "-m", "rigtool.watch.process", "--fd", str(listener.fileno()),
                 "--db", str(db), "--bind", bind],
                stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, pass_fds=(listener.fileno(),),
                start_new_session=True)  # a Ctrl-C meant for the sweep is the sweep's to handle
        finally:
            listener.close()  # the child holds its own copy

    def stop(self) -> None:
        """Close the child's input (it shuts down), and kill it if it has not within
        STOP_WAIT_S."""
        with contextlib.suppress(OSError):
            if self._proc.stdin is not None:
                self._proc.stdin.close()
        try:
            self._proc.wait(STOP_WAIT_S)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()


def _until_input_ends(server: WatchServer) -> None:
    """Shut `server` down once standard input reaches its end (the sweep is gone)."""
    with contextlib.suppress(OSError, ValueError):
        while sys.stdin.buffer.read(4096):
            pass
    server.shutdown()


def main(argv: list[str] | None = None) -> int:
    """Serve the watch page on an inherited listening socket until standard input ends."""
    from rigtool.watch.data import Watcher

    parser = argparse.ArgumentParser(prog="python -m rigtool.watch.process")
    parser.add_argument("--fd", type=int, required=True)
    parser.add_argument("--db", type=Path, required=True)
    parser.add_argument("--bind", required=True)
    args = parser.parse_args(argv)
    with contextlib.suppress(OSError):
        os.nice(WATCH_NICE)
    server = WatchServer(Watcher(args.db, follow=True), bind=args.bind,
                         listener=socket.socket(fileno=args.fd))
    threading.Thread(target=_until_input_ends, args=(server,), name="rigtool-watch-stdin",
                     daemon=True).start()
    try:
        server.serve_forever(poll_interval=0.5)
    finally:
        server.server_close()
        server.watcher.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
