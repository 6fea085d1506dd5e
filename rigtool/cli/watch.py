"""`rigtool watch`: serve a read-only web page following a run; and the same page beside a
sweep (`rigtool sweep --watch`)."""

from __future__ import annotations

import argparse
import contextlib
from pathlib import Path

from rigtool.cli.console import err, out
from rigtool.cli.options import DB, port_number
from rigtool.cli.signals import stop_on_signals
from rigtool.dbpath import resolve_db_path
from rigtool.errors import RigtoolError


def add_parsers(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("watch", help="serve a local, read-only web page following a run "
                       "(docs/watch.md)", parents=[DB])
    p.add_argument("run", nargs="?", default="last",
                   help="run id, unique prefix, or `last` (default: the run most recently started)")
    p.add_argument("--port", type=port_number, default=8765,
                   help="port (default 8765; 0: any free port)")
    p.add_argument("--bind", default="127.0.0.1", metavar="ADDRESS",
                   help="address to serve on (default 127.0.0.1: this host only; another "
                        "address opens the page to the network)")
    p.set_defaults(func=cmd_watch)


def cmd_watch(args: argparse.Namespace) -> int:
    from rigtool.watch import Watcher, WatchServer

    watcher = Watcher(resolve_db_path(args.db), args.run)
    try:
        run_id = watcher.start()
        server = WatchServer(watcher, args.port, args.bind)
    except BaseException:
        watcher.close()
        raise
    out.print(f"run {run_id}")
    announce_watch(server.url, args.bind, lasts="Ctrl-C stops it")
    try:
        with stop_on_signals():
            server.serve_forever(poll_interval=0.5)
    except KeyboardInterrupt:
        err.print("rigtool watch: stopped")
    finally:
        server.server_close()
        watcher.close()
    return 0


@contextlib.contextmanager
def watching(port: int | None, db: Path, bind: str):
    """With `--watch`: the watch server in a separate process beside the sweep, reading the
    latest run read-only, so that no client of the page reaches acquisition; a server that
    cannot start is a warning, never a reason to stop the sweep."""
    if port is None:
        yield
        return
    server = None
    try:
        from rigtool.watch.process import WatchProcess

        server = WatchProcess(db, port, bind)
        announce_watch(server.url, bind)
    except (OSError, RigtoolError) as exc:
        err.print(f"warning: rigtool watch could not start ({exc}); the sweep goes on without it")
    try:
        yield
    finally:
        if server is not None:
            with contextlib.suppress(BaseException):  # the run is closed: nothing to mask
                server.stop()


def announce_watch(url: str, bind: str, lasts: str = "served while the sweep runs") -> None:
    """Where the watch page is and how long it lasts (beside a sweep, Ctrl-C stops the sweep,
    not the page), and a warning when it is reachable from the network."""
    from rigtool.watch.server import is_loopback

    err.print(f"watch the run at {url} (read-only; {lasts})")
    if not is_loopback(bind):
        err.print(f"warning: the watch page is served on {bind}: anyone who can reach this "
                  "host can read the run (names, events, data); it commands nothing")
