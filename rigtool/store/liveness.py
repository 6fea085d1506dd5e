"""Whether a run's sweep process is still alive, and marking the runs whose process died
interrupted, so a crash never leaves a run `running` for ever."""

from __future__ import annotations

import logging
import os
import socket
import sqlite3
from pathlib import Path

from rigtool.errors import DataError, StoreError
from rigtool.ids import utc_now
from rigtool.readback import MAX_PID
from rigtool.store.connection import Transaction

log = logging.getLogger(__name__)


def _is_pid(value: object) -> bool:
    """Whether a stored pid is one a process could have (never 0, a group, or a text)."""
    return isinstance(value, int) and 0 < value <= MAX_PID


def owner_gone(host: object, pid: object) -> bool:
    """Whether a run's sweep process, on this host, no longer exists (False elsewhere)."""
    return host == socket.gethostname() and _is_pid(pid) and not _pid_alive(pid)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def mark_dead_runs_interrupted(conn: sqlite3.Connection, path: Path, read_only: bool,
                               timeout_s: float) -> None:
    """Mark runs whose sweep process died (same host, pid gone) interrupted.

    Best effort: on a full disk or a write-protected file the runs stay `running` and
    the next command that can write marks them. A read-only store writes through a
    second, short-lived connection, only when there is something to mark.
    """
    try:
        rows = conn.execute("SELECT id, host, pid FROM runs WHERE status = 'running'").fetchall()
    except (sqlite3.DatabaseError, DataError):
        return
    dead = [run_id for run_id, run_host, pid in rows if owner_gone(run_host, pid)]
    if not dead:
        return
    writer = conn
    try:
        if read_only:
            writer = sqlite3.connect(str(path), timeout=timeout_s, isolation_level=None)
        with Transaction(writer, path):
            for run_id in dead:
                writer.execute(
                    "UPDATE runs SET status = 'interrupted', finished_utc = ?, "
                    "stop_reason = ? WHERE id = ? AND status = 'running'",
                    (utc_now(), "the sweep process ended without closing the run", run_id))
    except (StoreError, sqlite3.DatabaseError, OSError) as exc:
        log.warning("warning: could not mark %d dead run(s) interrupted in %s (%s); the next "
                    "command that can write will", len(dead), path, exc)
    finally:
        if writer is not conn:
            writer.close()
