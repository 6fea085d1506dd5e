"""The row table rigtool stored samples in up to schema v7 (one row per sample), kept as the
baseline the benchmarks measure against: a bare sqlite3 `executemany` of the same rows, and a
bare read of them."""

from __future__ import annotations

import sqlite3
import time
from collections.abc import Iterator
from pathlib import Path

from rigtool.store import MIGRATIONS, SAMPLE_COLUMNS, Store

INSERT = (f"INSERT INTO samples ({', '.join(SAMPLE_COLUMNS)}) "
          f"VALUES ({', '.join('?' * len(SAMPLE_COLUMNS))})")


def connect(db: Path) -> sqlite3.Connection:
    """A database with rigtool's v7 schema and pragmas (WAL, synchronous=NORMAL)."""
    conn = sqlite3.connect(db, isolation_level=None)
    conn.execute("PRAGMA journal_mode=WAL")
    conn.execute("PRAGMA synchronous=NORMAL")
    if not conn.execute("SELECT count(*) FROM sqlite_master").fetchone()[0]:
        for migrate in MIGRATIONS[:7]:
            migrate(conn)
    return conn


def point_rows(store: Store, run_id: str) -> Iterator[list[tuple]]:
    """A stored run's samples as one list of row tuples per point (step ids as stored)."""
    for step in store.steps(run_id):
        cols = store.step_samples(step["id"], SAMPLE_COLUMNS[1:])
        yield list(zip([step["id"]] * step["n"], *(v.tolist() for v in cols.values()),
                       strict=True))


def timed_insert(conn: sqlite3.Connection, groups: list[list[tuple]]) -> float:
    """Seconds to insert the rows with executemany, one transaction per point."""
    t0 = time.perf_counter()
    for rows in groups:
        conn.execute("BEGIN IMMEDIATE")
        conn.executemany(INSERT, rows)
        conn.execute("COMMIT")
    return time.perf_counter() - t0


def copy_run(store: Store, run_id: str, db: Path) -> None:
    """Write a run's steps and samples into a v7 row database (for read baselines)."""
    conn = connect(db)
    cols = [c for c in (r[1] for r in conn.execute("PRAGMA table_info(steps)"))]
    conn.execute("BEGIN")
    for step in store.steps(run_id):
        conn.execute(f"INSERT INTO steps ({', '.join(cols)}) VALUES ({', '.join('?' * len(cols))})",
                     [step.get(c) for c in cols])
    conn.execute("INSERT INTO runs (id, name, status, created_utc, tool_version, host, pid, "
                 "protocol_json, rig_json, plan_json, metadata_json, n_planned, command_unit) "
                 "VALUES (?, 'copy', 'completed', '', '', '', 0, '{}', '{}', '[]', '{}', 0, '')",
                 (run_id,))
    conn.execute("COMMIT")
    for rows in point_rows(store, run_id):
        conn.execute("BEGIN")
        conn.executemany(INSERT, rows)
        conn.execute("COMMIT")
    conn.close()
