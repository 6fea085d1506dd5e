"""Connections to a run database: opening it for writing (WAL) or read-only, the UTF-8 text
factory, write transactions that turn SQLite's disk-full and lock errors into StoreError, and
the read-only, query-only opening of a database to merge from."""

from __future__ import annotations

import sqlite3
import time
from collections.abc import Callable
from pathlib import Path

from rigtool.errors import DataError, StoreError, UsageError
from rigtool.readback import show


def connect_writer(path: Path, create: bool, timeout_s: float) -> sqlite3.Connection:
    """A read-write connection in WAL mode with synchronous=NORMAL (the folder is made when
    `create`)."""
    if create:
        path.parent.mkdir(parents=True, exist_ok=True)
    conn = sqlite3.connect(str(path), timeout=timeout_s, isolation_level=None)
    _set_wal(conn, timeout_s)
    conn.execute("PRAGMA synchronous=NORMAL")
    return conn


def connect_read_only(path: Path, timeout_s: float) -> sqlite3.Connection:
    """A `mode=ro` connection. Where SQLite cannot create the WAL index beside a cleanly
    closed database (full disk, read-only folder), read the file as immutable: with no
    -wal file, the main file holds every committed row."""
    uri = path.resolve().as_uri()
    try:
        conn = sqlite3.connect(f"{uri}?mode=ro", uri=True, timeout=timeout_s,
                               isolation_level=None)
        conn.execute("SELECT count(*) FROM sqlite_master").fetchone()
        return conn
    except sqlite3.OperationalError:
        wal = path.with_name(path.name + "-wal")
        if wal.exists() and wal.stat().st_size > 0:
            raise
    return sqlite3.connect(f"{uri}?mode=ro&immutable=1", uri=True, timeout=timeout_s,
                           isolation_level=None)


def _set_wal(conn: sqlite3.Connection, timeout_s: float) -> None:
    """Switch to WAL, retrying while another process switches the same new file: SQLite
    reports that lock at once instead of waiting on the busy timeout."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            conn.execute("PRAGMA journal_mode=WAL")
            return
        except sqlite3.OperationalError as exc:
            if "locked" not in str(exc) or time.monotonic() > deadline:
                raise
            time.sleep(0.005)


def open_source(path: Path) -> sqlite3.Connection:
    """`path` read-only, query-only, and immutable unless its -wal holds commits."""
    if not path.is_file():
        raise UsageError(f"no run database at {path}")
    wal = path.with_name(path.name + "-wal")
    live = wal.exists() and wal.stat().st_size > 0
    uri = path.resolve().as_uri() + ("?mode=ro" if live else "?mode=ro&immutable=1")
    try:
        conn = sqlite3.connect(uri, uri=True, isolation_level=None)
        conn.text_factory = utf8_text(f"merge source {path}")
        conn.execute("PRAGMA query_only = ON")
        conn.execute("PRAGMA trusted_schema = OFF")
    except sqlite3.Error as exc:
        raise DataError(f"merge source {path}: cannot be opened ({exc})") from None
    return conn


class Transaction:
    """BEGIN IMMEDIATE ... COMMIT; disk-full, locked and read-only errors become StoreError."""

    def __init__(self, conn: sqlite3.Connection, path: Path) -> None:
        self.conn = conn
        self.path = path

    def _explain(self, exc: sqlite3.Error) -> StoreError:
        text = str(exc)
        if "locked" in text or "busy" in text:
            text += " (another process holds a write lock on it for too long)"
        return StoreError(f"run database {self.path}: {text}; nothing already committed is lost")

    def __enter__(self) -> sqlite3.Connection:
        if self.conn.in_transaction:  # left open by a signal between BEGIN and the with block
            self.conn.execute("ROLLBACK")  # (nothing nests transactions): its writes are not kept
        try:
            self.conn.execute("BEGIN IMMEDIATE")
            return self.conn
        except sqlite3.OperationalError as exc:
            raise self._explain(exc) from exc
        except BaseException:
            if self.conn.in_transaction:
                self.conn.execute("ROLLBACK")
            raise

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            try:
                self.conn.execute("COMMIT")
                return
            except sqlite3.OperationalError as commit_exc:
                exc = commit_exc
        if self.conn.in_transaction:
            self.conn.execute("ROLLBACK")
        if isinstance(exc, sqlite3.OperationalError):
            raise self._explain(exc) from exc


class NotUtf8(DataError):
    """A stored text that is not UTF-8, met while a row is fetched."""

    def __init__(self, label: str, raw: bytes) -> None:
        self.problem = f"a text is not UTF-8 ({show(raw)})"
        super().__init__(f"{label}: {self.problem} (the database is damaged or was edited)")


def utf8_text(label: str) -> Callable[[bytes], str]:
    """A connection's text factory: UTF-8, and a DataError for anything else."""
    def decode(raw: bytes) -> str:
        """`raw` as UTF-8 text."""
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            raise NotUtf8(label, raw) from None
    return decode
