"""`Store`, the run database: opening it (created and migrated, or read-only), then the
single writer (rigtool.store.writer) and the checked queries (rigtool.store.queries)."""

from __future__ import annotations

import sqlite3
from pathlib import Path

from rigtool.dbpath import DB_ENV
from rigtool.errors import StoreError, UsageError
from rigtool.store import schema
from rigtool.store.connection import connect_read_only, connect_writer, utf8_text
from rigtool.store.liveness import mark_dead_runs_interrupted
from rigtool.store.writer import RunWriter


class Store(RunWriter):
    """The run database. One instance is the single writer of a sweep."""

    def __init__(self, path: str | Path, *, create: bool = True, timeout_s: float = 10.0,
                 read_only: bool = False) -> None:
        """Open (or create) the database. `read_only` is for commands that only read: they
        work on a full disk or a write-protected file, and never migrate or mark runs."""
        self.path = Path(path)
        self.read_only = read_only
        if (read_only or not create) and not self.path.exists():
            raise UsageError(f"no run database at {self.path} (use --db or set ${DB_ENV})")
        try:
            if read_only:
                self.conn = connect_read_only(self.path, timeout_s)
            else:
                self.conn = connect_writer(self.path, create, timeout_s)
            self.conn.execute("PRAGMA foreign_keys=ON")
            self.conn.text_factory = utf8_text(f"run database {self.path}")
            if read_only:
                schema.check_readable(self.conn, self.path)
            else:
                schema.upgrade(self.conn, self.path)
        except (sqlite3.DatabaseError, OSError) as exc:
            raise StoreError(f"cannot open run database {self.path}: {exc}") from exc
        mark_dead_runs_interrupted(self.conn, self.path, self.read_only, timeout_s)

    def close(self) -> None:
        """Close the connection; closing twice is harmless."""
        self.conn.close()

    def __enter__(self) -> Store:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
