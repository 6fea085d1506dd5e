"""SQLite run store: schema, migrations, the single writer, and queries.

Fixed tables (runs, steps, sample_blocks, events, calibrations) in WAL mode; the schema
version lives in PRAGMA user_version. A point's samples are stored as column BLOBs
(little-endian float64, NaN for a missing value, NULL for an absent channel) in blocks of
at most SAMPLES_PER_CHUNK, inserted with the step they belong to in one transaction, so a
crash never leaves half a point. docs/performance.md has the measurements behind the layout.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import itertools
import json
import logging
import os
import re
import secrets
import socket
import sqlite3
import time
from collections import Counter
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from rigtool.errors import DataError, StoreError, UsageError
from rigtool.readback import (
    CALIBRATION_COLUMNS,
    EVENT_COLUMNS,
    MAX_CHUNK,
    MAX_EVENT_BYTES,
    MAX_ID_TEXT,
    MAX_MERGE_RUNS,
    MAX_PID,
    MAX_STORED_CALIBRATIONS,
    MAX_STORED_EVENTS,
    MAX_STORED_POINTS,
    RUN_COLUMNS,
    STEP_COLUMNS,
    Column,
    Invalid,
    event_detail,
    show,
)
from rigtool.spool import SAMPLES_PER_CHUNK, SampleSpool

log = logging.getLogger(__name__)

DB_ENV = "RIGTOOL_DB"
DEFAULT_DB = "rigtool.sqlite"

RUN_STATUSES = ("running", "completed", "aborted", "failed", "interrupted")

SAMPLE_COLUMNS = (
    "step_id", "t_s", "fx", "fy", "fz", "tx", "ty", "tz",
    "thrust_n", "speed_rpm", "current_a", "voltage_v", "command", "seq",
)

STAT_FIELDS = ("thrust_n", "speed_rpm", "current_a")

# A stored point's columns under the names the API, points.csv and the exports use
# (public name -> steps column). Statistics here are over all of a point's samples.
POINT_COLUMNS = {
    "step_idx": "idx", "command": "command", "depth_m": "depth_m", "voltage_set_v": "voltage_v",
    "repeat": "repeat",
    "direction": "direction", "status": "status", "settled": "settled",
    "t_start_s": "t_start_s", "t_acquire_s": "t_acquire_s", "t_end_s": "t_end_s",
    "settle_s": "settle_s", "rate_hz": "rate_hz", "n_samples": "n",
    **{f"{ch}_{stat}_{u}": f"{field}_{stat}"
       for field, ch, u in (("thrust_n", "thrust", "n"), ("speed_rpm", "speed", "rpm"),
                            ("current_a", "current", "a"))
       for stat in ("mean", "std", "min", "max")},
}
TEXT_POINT_COLUMNS = ("direction", "status")
INT_POINT_COLUMNS = ("step_idx", "repeat", "settled", "n_samples")
INT_SAMPLE_COLUMNS = ("step_idx", "seq")
MISSING_INT = -1  # an integer column's value where the store has none (seq of old runs)


@dataclass(frozen=True)
class RunRecord:
    """One stored run, typed: what analysis and the API need without digging in JSON.

    `neutral` is the actuator's recorded neutral; older and imported runs fall back to the
    protocol's `command.neutral`, then to the usual neutral of the unit.
    """

    id: str
    name: str
    status: str
    created_utc: str
    finished_utc: str | None
    stop_reason: str | None
    tool_version: str
    seed: int | None
    n_planned: int
    command_unit: str
    neutral: float
    command_min: float | None
    command_max: float | None
    thruster_id: str | None
    propeller_diameter_m: float | None
    water_density_kg_m3: float | None
    rig_name: str | None
    metadata: dict
    protocol: dict
    rig: dict

# Bulk writes (imports): point rows per executemany call, and samples per transaction, so a
# big import holds the write lock briefly and never builds all blocks at once.
BATCH_ROWS = 10_000
IMPORT_ROWS_PER_TRANSACTION = 1_000_000
READ_SAMPLES = SAMPLES_PER_CHUNK  # samples per chunk `iter_samples` yields (13 columns: ~7 MB)
BLOB_DTYPE = np.dtype("<f8")

# Transport counters that count ordinary traffic; every other counter a driver keeps
# (garbage, lost_packets, timeouts, error_frames...) is a problem a reader should see.
TRAFFIC_COUNTERS = frozenset({"frames", "datagrams", "records", "sent", "replies", "heartbeats",
                              "telemetry", "lines", "readings", "queries", "starts", "ignored"})

SCHEMA_V1 = """
CREATE TABLE runs (
    id TEXT PRIMARY KEY,
    name TEXT NOT NULL,
    status TEXT NOT NULL,
    created_utc TEXT NOT NULL,
    finished_utc TEXT,
    tool_version TEXT NOT NULL,
    host TEXT NOT NULL,
    pid INTEGER NOT NULL,
    seed INTEGER,
    protocol_path TEXT,
    protocol_json TEXT NOT NULL,
    rig_json TEXT NOT NULL,
    plan_json TEXT NOT NULL,
    metadata_json TEXT NOT NULL,
    n_planned INTEGER NOT NULL,
    command_unit TEXT NOT NULL,
    stop_reason TEXT
);
CREATE TABLE steps (
    id INTEGER PRIMARY KEY,
    run_id TEXT NOT NULL REFERENCES runs(id),
    idx INTEGER NOT NULL,
    command REAL NOT NULL,
    command_unit TEXT NOT NULL,
    depth_m REAL,
    repeat INTEGER NOT NULL,
    direction TEXT NOT NULL,
    t_start_s REAL NOT NULL,
    t_acquire_s REAL NOT NULL,
    t_end_s REAL NOT NULL,
    settle_s REAL NOT NULL,
    settled INTEGER NOT NULL,
    rate_hz REAL NOT NULL,
    status TEXT NOT NULL,
    n INTEGER NOT NULL,
    thrust_n_mean REAL, thrust_n_std REAL, thrust_n_min REAL, thrust_n_max REAL,
    speed_rpm_mean REAL, speed_rpm_std REAL, speed_rpm_min REAL, speed_rpm_max REAL,
    current_a_mean REAL, current_a_std REAL, current_a_min REAL, current_a_max REAL,
    UNIQUE (run_id, idx)
);
CREATE TABLE samples (
    step_id INTEGER NOT NULL REFERENCES steps(id),
    t_s REAL NOT NULL,
    fx REAL, fy REAL, fz REAL, tx REAL, ty REAL, tz REAL,
    thrust_n REAL,
    speed_rpm REAL,
    current_a REAL,
    voltage_v REAL,
    command REAL
);
CREATE INDEX samples_step ON samples(step_id);
CREATE TABLE events (
    id INTEGER PRIMARY KEY,
    run_id TEXT NOT NULL REFERENCES runs(id),
    t_s REAL,
    kind TEXT NOT NULL,
    step_idx INTEGER,
    detail_json TEXT NOT NULL
);
CREATE INDEX events_run ON events(run_id, kind);
CREATE TABLE calibrations (
    id INTEGER PRIMARY KEY,
    run_id TEXT NOT NULL REFERENCES runs(id),
    created_utc TEXT NOT NULL,
    tool_version TEXT NOT NULL,
    out_dir TEXT NOT NULL,
    summary_json TEXT NOT NULL
);
"""



def _execute_script(conn: sqlite3.Connection, script: str) -> None:
    """Run `;`-separated DDL inside the caller's transaction (executescript would commit)."""
    for statement in script.split(";"):
        if statement.strip():
            conn.execute(statement)


# Each migration takes the store from version i to i + 1.
MIGRATIONS: list[Callable[[sqlite3.Connection], None]] = [
    lambda conn: _execute_script(conn, SCHEMA_V1),
    # v2: the sensor's own sample sequence number, to reconcile lost samples
    lambda conn: conn.execute("ALTER TABLE samples ADD COLUMN seq INTEGER"),
    # v3: the actuator that ran the run (unit, neutral, range), so analysis need not guess
    lambda conn: conn.execute("ALTER TABLE runs ADD COLUMN actuator_json TEXT"),
    # v4: when the run was last started or resumed, which `last` resolves by
    lambda conn: _execute_script(conn, "ALTER TABLE runs ADD COLUMN started_utc TEXT; "
                                       "UPDATE runs SET started_utc = created_utc"),
    # v5: what each device's transport counters (frames, garbage, lost...) added during a point
    lambda conn: conn.execute("ALTER TABLE steps ADD COLUMN counters_json TEXT"),
    # v6: the analysis results a calibration found, which `report` and the API render
    lambda conn: conn.execute("ALTER TABLE calibrations ADD COLUMN state BLOB"),
    # v7: the supply voltage set for a point (NULL when the protocol sweeps none)
    lambda conn: conn.execute("ALTER TABLE steps ADD COLUMN voltage_v REAL"),
    # v8: samples as per-point column BLOBs instead of one row per sample
    lambda conn: _samples_to_blocks(conn),
]
SCHEMA_VERSION = len(MIGRATIONS)


def create_schema(conn: sqlite3.Connection) -> None:
    """Apply every migration to an empty database (for tools and benchmarks)."""
    for migrate in MIGRATIONS:
        migrate(conn)
    conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")


def utc_now(timespec: str = "seconds") -> str:
    """ISO-8601 UTC timestamp, to the second unless `timespec` asks for finer."""
    return datetime.now(timezone.utc).isoformat(timespec=timespec)


def new_run_id() -> str:
    """Sortable, cross-machine unique id: UTC time to the millisecond plus 24 random bits."""
    now = datetime.now(timezone.utc)
    return now.strftime("%Y%m%dT%H%M%S") + f"{now.microsecond // 1000:03d}Z-" + secrets.token_hex(3)


RUN_ID_GRAMMAR = re.compile(r"\d{8}T\d{9}Z-[0-9a-f]{6}")  # what new_run_id makes


def is_run_id(text: object) -> bool:
    """Whether `text` is a run id as `new_run_id` makes them (safe as a file name)."""
    return isinstance(text, str) and RUN_ID_GRAMMAR.fullmatch(text) is not None


def run_label(run_id: object) -> str:
    """A run id for a one-line message: as it is when well formed, else quoted and cut."""
    return run_id if is_run_id(run_id) else show(run_id)  # type: ignore[return-value]


def resolve_db_path(cli_value: str | None, rig_value: str | None = None) -> Path:
    """DB path from --db, then $RIGTOOL_DB, then the rig file, then ./rigtool.sqlite."""
    return Path(cli_value or os.environ.get(DB_ENV) or rig_value or DEFAULT_DB)


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


@dataclass
class StepRecord:
    """One completed point, as the engine hands it to the store."""

    idx: int
    command: float
    command_unit: str
    depth_m: float | None
    repeat: int
    direction: str
    t_start_s: float
    t_acquire_s: float
    t_end_s: float
    settle_s: float
    settled: bool
    rate_hz: float
    status: str = "ok"
    counters: dict | None = None  # transport counters added during the point, by device role
    voltage_v: float | None = None  # supply voltage set for the point (None: not swept)


class Store:
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
                self.conn = self._connect_read_only(timeout_s)
            else:
                if create:
                    self.path.parent.mkdir(parents=True, exist_ok=True)
                self.conn = sqlite3.connect(str(self.path), timeout=timeout_s, isolation_level=None)
                self._set_wal(timeout_s)
                self.conn.execute("PRAGMA synchronous=NORMAL")
            self.conn.execute("PRAGMA foreign_keys=ON")
            self.conn.text_factory = _utf8_text(f"run database {self.path}")
            if read_only:
                self._check_readable()
            else:
                self._migrate()
        except (sqlite3.DatabaseError, OSError) as exc:
            raise StoreError(f"cannot open run database {self.path}: {exc}") from exc
        self._mark_dead_runs_interrupted(timeout_s)

    def _connect_read_only(self, timeout_s: float) -> sqlite3.Connection:
        """A `mode=ro` connection. Where SQLite cannot create the WAL index beside a cleanly
        closed database (full disk, read-only folder), read the file as immutable: with no
        -wal file, the main file holds every committed row."""
        uri = self.path.resolve().as_uri()
        try:
            conn = sqlite3.connect(f"{uri}?mode=ro", uri=True, timeout=timeout_s,
                                   isolation_level=None)
            conn.execute("SELECT count(*) FROM sqlite_master").fetchone()
            return conn
        except sqlite3.OperationalError:
            wal = self.path.with_name(self.path.name + "-wal")
            if wal.exists() and wal.stat().st_size > 0:
                raise
        return sqlite3.connect(f"{uri}?mode=ro&immutable=1", uri=True, timeout=timeout_s,
                               isolation_level=None)

    def _check_readable(self) -> None:
        """A read-only open cannot migrate: an older schema asks for one writing command."""
        current = self.version
        if current > SCHEMA_VERSION:
            raise StoreError(f"{self.path} has schema version {current}; this rigtool knows up "
                             f"to {SCHEMA_VERSION}: upgrade rigtool")
        if current < SCHEMA_VERSION:
            raise StoreError(
                f"{self.path} has schema version {current} and needs a one-time upgrade to "
                f"{SCHEMA_VERSION}, which writes to it: run `rigtool calibrate` or `rigtool "
                "sweep` on it once, with free disk space and write access")

    def _set_wal(self, timeout_s: float) -> None:
        """Switch to WAL, retrying while another process switches the same new file: SQLite
        reports that lock at once instead of waiting on the busy timeout."""
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                self.conn.execute("PRAGMA journal_mode=WAL")
                return
            except sqlite3.OperationalError as exc:
                if "locked" not in str(exc) or time.monotonic() > deadline:
                    raise
                time.sleep(0.005)

    # -- schema ---------------------------------------------------------------------------
    @property
    def version(self) -> int:
        return self.conn.execute("PRAGMA user_version").fetchone()[0]

    def _migrate(self) -> None:
        """Bring the schema up to date, one migration per transaction.

        The version is re-read under the write lock, so two processes opening a new
        database at once never apply the same migration twice.
        """
        while (current := self.version) != SCHEMA_VERSION:
            if current > SCHEMA_VERSION:
                raise StoreError(
                    f"{self.path} has schema version {current}; this rigtool knows up to "
                    f"{SCHEMA_VERSION}: upgrade rigtool"
                )
            with self.transaction():
                if self.version == current:
                    MIGRATIONS[current](self.conn)
                    self.conn.execute(f"PRAGMA user_version = {current + 1}")

    def _mark_dead_runs_interrupted(self, timeout_s: float) -> None:
        """Mark runs whose sweep process died (same host, pid gone) interrupted.

        Best effort: on a full disk or a write-protected file the runs stay `running` and
        the next command that can write marks them. A read-only store writes through a
        second, short-lived connection, only when there is something to mark.
        """
        try:
            rows = self.conn.execute(
                "SELECT id, host, pid FROM runs WHERE status = 'running'").fetchall()
        except (sqlite3.DatabaseError, DataError):
            return
        dead = [run_id for run_id, run_host, pid in rows if owner_gone(run_host, pid)]
        if not dead:
            return
        conn = self.conn
        try:
            if self.read_only:
                conn = sqlite3.connect(str(self.path), timeout=timeout_s, isolation_level=None)
            with _Transaction(conn, self.path):
                for run_id in dead:
                    conn.execute(
                        "UPDATE runs SET status = 'interrupted', finished_utc = ?, "
                        "stop_reason = ? WHERE id = ? AND status = 'running'",
                        (utc_now(), "the sweep process ended without closing the run", run_id))
        except (StoreError, sqlite3.DatabaseError, OSError) as exc:
            log.warning("warning: could not mark %d dead run(s) interrupted in %s (%s); the next command "
                        "that can write will", len(dead), self.path, exc)
        finally:
            if conn is not self.conn:
                conn.close()

    @contextlib.contextmanager
    def snapshot(self) -> Iterator[None]:
        """Read in one transaction: every query inside sees the database as it was at the
        first, even while a sweep appends points. Nested use joins the outer snapshot; the
        outermost ends the transaction when it exits, also on an exception."""
        if self.conn.in_transaction:
            yield
            return
        self.conn.execute("BEGIN")
        try:
            yield
        finally:
            self._end_read()

    def _end_read(self) -> None:
        """End a snapshot's read transaction (nothing to end once the store is closed)."""
        with contextlib.suppress(sqlite3.ProgrammingError):
            if self.conn.in_transaction:
                self.conn.execute("COMMIT")

    @property
    def in_snapshot(self) -> bool:
        """Whether a snapshot (or any transaction) is open on this store's connection."""
        return self.conn.in_transaction

    def transaction(self) -> _Transaction:
        """Context manager: BEGIN IMMEDIATE ... COMMIT, or ROLLBACK on error."""
        return _Transaction(self.conn, self.path)

    def close(self) -> None:
        """Close the connection; closing twice is harmless."""
        self.conn.close()

    def __enter__(self) -> Store:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- writing --------------------------------------------------------------------------
    def create_run(
        self,
        *,
        name: str,
        protocol: dict,
        protocol_path: str | None,
        rig: dict,
        plan: list[dict],
        metadata: dict,
        seed: int | None,
        command_unit: str,
        tool_version: str,
        actuator: dict | None = None,
        status: str = "running",
        stop_reason: str | None = None,
    ) -> str:
        """Insert a new run (running, unless an import marks it incomplete until it is done);
        `actuator` is its command space (unit, neutral, range)."""
        if status not in RUN_STATUSES:
            raise ValueError(f"unknown run status {status!r}")
        run_id = new_run_id()
        row = {
            "id": run_id,
            "name": name,
            "status": status,
            "created_utc": utc_now(),
            "finished_utc": None,
            "tool_version": tool_version,
            "host": socket.gethostname(),
            "pid": os.getpid(),
            "seed": seed,
            "protocol_path": protocol_path,
            "protocol_json": json.dumps(protocol),
            "rig_json": json.dumps(rig),
            "plan_json": json.dumps(plan),
            "metadata_json": json.dumps(metadata),
            "n_planned": len(plan),
            "command_unit": command_unit,
            "stop_reason": stop_reason,
            "actuator_json": None if actuator is None else json.dumps(actuator),
            "started_utc": utc_now("microseconds"),
        }
        with self.transaction() as conn:
            conn.execute(f"INSERT INTO runs ({', '.join(row)}) VALUES "
                         f"({', '.join('?' * len(row))})", tuple(row.values()))
        return run_id

    def add_step(
        self,
        run_id: str,
        step: StepRecord,
        samples: dict[str, np.ndarray] | SampleSpool,
    ) -> int:
        """Insert one point and all its samples in a single transaction; return the step id.

        `samples` is a dict of arrays or the engine's SampleSpool; rows go to SQLite in
        blocks, so memory stays bounded however many samples the point has.
        """
        spool = samples if isinstance(samples, SampleSpool) else SampleSpool.of(
            samples, SAMPLE_COLUMNS[1:], STAT_FIELDS)
        fields = dict(step.__dict__)
        counters = fields.pop("counters")
        row: dict[str, Any] = {"run_id": run_id, **fields, "n": spool.n,
                               "counters_json": json.dumps(counters) if counters else None}
        row["settled"] = int(step.settled)
        for name in STAT_FIELDS:
            keys = [f"{name}_{s}" for s in ("mean", "std", "min", "max")]
            row.update(zip(keys, spool.stats(name) or (None,) * 4, strict=True))
        with self.transaction():
            cur = self.conn.execute(
                f"INSERT INTO steps ({', '.join(row)}) VALUES ({', '.join('?' * len(row))})",
                list(row.values()),
            )
            step_id = cur.lastrowid
            self.conn.executemany(INSERT_BLOCK, (_block_row(step_id, k, chunk) for k, chunk
                                                 in enumerate(spool.column_chunks())))
        return step_id

    def add_points(self, run_id: str, points: dict[str, np.ndarray], bounds: np.ndarray,
                   samples: dict[str, np.ndarray], command_unit: str) -> None:
        """Insert many finished points (idx 0, 1, ...) with their samples, for imports.

        Point i owns samples[c][bounds[i]:bounds[i + 1]]; `points` holds the StepRecord fields
        command, depth_m (NaN = none), repeat, direction, t_*_s, settle_s and rate_hz as
        arrays. Points go in with executemany in batches of BATCH_ROWS, in transactions of at
        most IMPORT_ROWS_PER_TRANSACTION samples (one point never splits).
        """
        bounds = np.asarray(bounds, dtype=np.int64)
        n_points = bounds.size - 1
        if n_points and np.any(np.diff(bounds) < 1):
            raise ValueError("every point needs at least one sample")
        columns: dict[str, list] = {k: np.asarray(v).tolist() for k, v in points.items()}
        n = np.diff(bounds)
        columns["n"] = n.tolist()
        for name in STAT_FIELDS:
            stats = segment_stats(samples.get(name), bounds)
            for key, values in stats.items():
                columns[f"{name}_{key}"] = values
        start = 0
        while start < n_points:
            limit = bounds[start] + IMPORT_ROWS_PER_TRANSACTION
            stop = min(n_points, max(start + 1, int(np.searchsorted(bounds, limit, "right")) - 1))
            with self.transaction():
                self._insert_points(run_id, columns, bounds, samples, command_unit, start, stop)
            start = stop

    def _insert_points(self, run_id: str, columns: dict[str, list], bounds: np.ndarray,
                       samples: dict[str, np.ndarray], command_unit: str, start: int,
                       stop: int) -> None:
        """Points start..stop-1 and their samples, inside the caller's transaction."""
        first_id = self.conn.execute("SELECT COALESCE(MAX(id), 0) + 1 FROM steps").fetchone()[0]
        filled = {k: v for k, v in columns.items() if any(x is not None for x in v[start:stop])}
        names = ["id", "run_id", "idx", "command_unit", "settled", "status", *filled]
        sql = f"INSERT INTO steps ({', '.join(names)}) VALUES ({', '.join('?' * len(names))})"
        for a in range(start, stop, BATCH_ROWS):
            b = min(stop, a + BATCH_ROWS)
            self.conn.executemany(sql, zip(
                range(first_id + a - start, first_id + b - start), itertools.repeat(run_id),
                range(a, b), itertools.repeat(command_unit), itertools.repeat(1),
                itertools.repeat("ok"), *(values[a:b] for values in filled.values())))
        names = [c for c in SAMPLE_COLUMNS[1:] if samples.get(c) is not None]
        self.conn.executemany(INSERT_BLOCK, (
            _block_row(first_id + i - start, k, {
                c: samples[c][a:min(a + SAMPLES_PER_CHUNK, int(bounds[i + 1]))] for c in names})
            for i in range(start, stop)
            for k, a in enumerate(range(int(bounds[i]), int(bounds[i + 1]), SAMPLES_PER_CHUNK))))

    def add_events(self, run_id: str, events: list[tuple[str, dict]]) -> None:
        """Insert several (kind, detail) events of a run in one transaction."""
        with self.transaction():
            self.conn.executemany(
                "INSERT INTO events (run_id, t_s, kind, step_idx, detail_json) "
                "VALUES (?, NULL, ?, NULL, ?)",
                [(run_id, kind, json.dumps(detail)) for kind, detail in events])

    def add_event(
        self, run_id: str, kind: str, detail: dict | None = None,
        t_s: float | None = None, step_idx: int | None = None,
    ) -> None:
        with self.transaction():
            self.conn.execute(
                "INSERT INTO events (run_id, t_s, kind, step_idx, detail_json) VALUES (?, ?, ?, ?, ?)",
                (run_id, t_s, kind, step_idx, json.dumps(detail or {})),
            )

    def finish_run(self, run_id: str, status: str, reason: str | None = None) -> None:
        if status not in RUN_STATUSES:
            raise ValueError(f"unknown run status {status!r}")
        with self.transaction():
            self.conn.execute(
                "UPDATE runs SET status = ?, finished_utc = ?, stop_reason = ? WHERE id = ?",
                (status, utc_now(), reason, run_id),
            )

    def reopen_run(self, run_id: str) -> None:
        """Mark an interrupted/aborted/failed run as running again, owned by this process.

        A single conditional UPDATE, so two resumes of one run cannot both win. The run
        becomes `last` (see `resolve_run_id`).
        """
        with self.transaction():
            cur = self.conn.execute(
                "UPDATE runs SET status = 'running', finished_utc = NULL, stop_reason = NULL, "
                "host = ?, pid = ?, started_utc = ? "
                "WHERE id = ? AND status IN ('interrupted', 'aborted', 'failed')",
                (socket.gethostname(), os.getpid(), utc_now("microseconds"), run_id),
            )
        if cur.rowcount != 1:
            raise UsageError(f"run {run_id} is no longer resumable (another process resumed it?)")

    def add_calibration(self, run_id: str, out_dir: str, summary: dict, tool_version: str,
                        state: bytes | None = None, created_utc: str | None = None) -> None:
        """Record a calibration: its folder, its calibration.json content and (`state`) the
        encoded analysis results that `report` renders."""
        with self.transaction():
            self.conn.execute(
                "INSERT INTO calibrations (run_id, created_utc, tool_version, out_dir, "
                "summary_json, state) VALUES (?, ?, ?, ?, ?, ?)",
                (run_id, created_utc or utc_now(), tool_version, out_dir, json.dumps(summary),
                 state))

    def replace_events(self, run_id: str, kind: str, records: list[dict],
                       t_key: str = "t_start_s", step_key: str = "step_idx") -> None:
        """Replace a run's events of `kind` by `records` in one transaction (a rerun of an
        analysis must not duplicate them)."""
        with self.transaction() as conn:
            conn.execute("DELETE FROM events WHERE run_id = ? AND kind = ?", (run_id, kind))
            conn.executemany(
                "INSERT INTO events (run_id, t_s, kind, step_idx, detail_json) "
                "VALUES (?, ?, ?, ?, ?)",
                [(run_id, r.get(t_key), kind, r.get(step_key), json.dumps(r)) for r in records])

    def merge_from(self, sources: Iterable[str | Path]) -> list[MergeReport]:
        """Merge other stores into this one, every row checked first: a run this one lacks is
        copied (run, points under new step ids, samples, events, calibrations); of a run it
        has, what is new is brought over: points it lacks, a later status (a resumed run),
        calibrations and events. A point both hold must be identical (fields, and its sample
        blocks by hash), else MergeConflict; nothing is overwritten. A run still running in
        a source is left for a later merge, one running here is not touched. Merging again
        changes nothing.

        The whole merge is one transaction: any refused row rolls all of it back. Sources
        are opened read-only (immutable when they have no write-ahead log), so not even
        their -wal or -shm files are created. Returns a MergeReport per source.
        """
        opened = []
        try:
            for path in sources:
                opened.append(_MergeSource(Path(path), self.version))
            with self.transaction():
                here = set(self.run_ids())
                return [src.copy_into(self._read, here) for src in opened]
        finally:
            for src in opened:
                src.close()

    # -- reading --------------------------------------------------------------------------
    @property
    def _read(self) -> _Reader:
        """Checked reads from this store's connection."""
        return _Reader(self.conn, f"run database {self.path}")

    def resolve_run_id(self, ref: str) -> str:
        """Accept a full id, an unambiguous literal id prefix, or `last`: the run most
        recently started or resumed. An empty or blank reference matches nothing."""
        if not ref.strip():
            raise UsageError(f"empty run id {ref!r}: give a run id, a prefix of one, or `last`")
        self._read.find_bad(None, "runs", ("id", "started_utc"), "1", ())
        if ref == "last":
            row = self.conn.execute(
                "SELECT id FROM runs ORDER BY started_utc DESC, id DESC LIMIT 1").fetchone()
            if row is None:
                raise UsageError(f"no runs in {self.path} yet: run `rigtool sweep` first")
            return self._run_id(row[0])
        rows = self.conn.execute(
            "SELECT id FROM runs WHERE substr(id, 1, ?) = ? ORDER BY id", (len(ref), ref)
        ).fetchall()
        if not rows:
            raise UsageError(f"no run {ref!r} in {self.path} (see `rigtool runs`)")
        ids = [self._run_id(r[0]) for r in rows[:5]]
        if len(rows) > 1:
            raise UsageError(f"run id prefix {ref!r} is ambiguous: {', '.join(ids)}")
        return ids[0]

    def _run_id(self, value: object) -> str:
        """A run id read from the runs table, checked to be text."""
        try:
            return RUN_COLUMNS["id"].check(value)
        except Invalid as exc:
            raise self._read.damaged(value, "runs.id", str(exc)) from None

    def run(self, run_id: str) -> dict:
        """The stored run: its columns, with protocol, rig, plan, metadata and actuator parsed
        from JSON and checked (DataError names the run and the field)."""
        rows = list(self._read.rows(run_id, "runs", tuple(RUN_COLUMNS), "id = ?", (run_id,)))
        if not rows:
            raise UsageError(f"no run {run_id!r} in {self.path}")
        out = rows[0]
        for key in ("protocol_json", "rig_json", "plan_json", "metadata_json", "actuator_json"):
            out[key.removesuffix("_json")] = out.pop(key)
        return out

    def run_record(self, run_id: str) -> RunRecord:
        """The typed record of a stored run."""
        from rigtool.units import NEUTRAL_BY_UNIT

        run = self.run(run_id)
        protocol = run.get("protocol") or {}
        command = protocol.get("command") or {}
        meta = {**(protocol.get("metadata") or {}), **(run.get("metadata") or {})}
        actuator = run.get("actuator") or {}
        unit = run.get("command_unit") or command.get("unit") or "percent"
        neutral = next((v for v in (actuator.get("neutral"), command.get("neutral"))
                        if v is not None), NEUTRAL_BY_UNIT.get(unit, 0.0))
        return RunRecord(
            id=run_id, name=run["name"], status=run["status"], created_utc=run["created_utc"],
            finished_utc=run.get("finished_utc"), stop_reason=run.get("stop_reason"),
            tool_version=run["tool_version"], seed=run.get("seed"), n_planned=run["n_planned"],
            command_unit=unit, neutral=float(neutral),
            command_min=_opt_float(actuator.get("command_min")),
            command_max=_opt_float(actuator.get("command_max")),
            thruster_id=None if meta.get("thruster_id") is None else str(meta["thruster_id"]),
            propeller_diameter_m=_opt_float(meta.get("propeller_diameter_m")),
            water_density_kg_m3=_opt_float(meta.get("water_density_kg_m3")),
            rig_name=(run.get("rig") or {}).get("name"), metadata=run.get("metadata") or {},
            protocol=protocol, rig=run.get("rig") or {})

    def points(self, run_id: str) -> dict[str, np.ndarray]:
        """A run's stored points as columns under POINT_COLUMNS' public names, in plan order."""
        rows = self._step_rows(run_id, tuple(dict.fromkeys(POINT_COLUMNS.values())))
        out = {}
        for name, column in POINT_COLUMNS.items():
            values = [r[column] for r in rows]
            if name in TEXT_POINT_COLUMNS:
                out[name] = np.array(values, dtype=str)
            elif name in INT_POINT_COLUMNS:
                out[name] = np.array(values, dtype=np.int64)
            else:
                out[name] = np.array([np.nan if v is None else v for v in values], dtype=float)
        return out

    def _step_rows(self, run_id: str, names: Sequence[str], where: str = "",
                   parse: bool = False) -> list[dict]:
        """Checked rows of a run's points in plan order (JSON parsed only if `parse`)."""
        self._read.count(run_id, "steps", "run_id = ?", (run_id,), MAX_STORED_POINTS)
        return list(self._read.rows(run_id, "steps", names, "run_id = ?" + where, (run_id,),
                                    "ORDER BY idx", parse=parse))

    def sample_arrays(self, run_id: str, columns: Iterable[str] | None = None,
                      steps: Iterable[int] | None = None) -> dict[str, np.ndarray]:
        """Samples of a run (or of the points whose plan index is in `steps`) as columns:
        `step_idx` (the plan index) and `seq` as int64 (MISSING_INT where unrecorded), every
        other column float64 with NaN for NULL; in acquisition order."""
        chunks = list(self.iter_samples(run_id, columns, steps))
        if not chunks:
            return self._sample_columns([], self._sample_names(columns))
        return {c: np.concatenate([ch[c] for ch in chunks]) for c in chunks[0]}

    def iter_samples(self, run_id: str, columns: Iterable[str] | None = None,
                     steps: Iterable[int] | None = None, batch: int = READ_SAMPLES
                     ) -> Iterator[dict[str, np.ndarray]]:
        """`sample_arrays` in chunks of about `batch` samples (stored blocks never split, so
        a chunk holds at most batch + SAMPLES_PER_CHUNK), for exports of any size."""
        cols = self._sample_names(columns)
        self._read.check_blocks(run_id, "st.run_id = ?", (run_id,))
        sql = (f"SELECT st.idx, b.n{''.join(', b.' + c for c in cols[1:])} FROM sample_blocks b "
               "JOIN steps st ON st.id = b.step_id WHERE st.run_id = ?")
        args: list[Any] = [run_id]
        if steps is not None:
            wanted = sorted({int(i) for i in steps})
            sql += f" AND st.idx IN ({', '.join('?' * len(wanted))})"
            args += wanted
        pending: list[tuple] = []
        held = 0
        for row in self.conn.execute(sql + " ORDER BY st.idx, b.chunk", args):
            pending.append(row)
            held += row[1]
            if held >= batch:
                yield self._sample_columns(pending, cols)
                pending, held = [], 0
        if pending:
            yield self._sample_columns(pending, cols)

    @staticmethod
    def _sample_names(columns: Iterable[str] | None) -> list[str]:
        cols = ["step_idx", *(c for c in (columns or SAMPLE_COLUMNS[1:]) if c != "step_idx")]
        _checked_columns(cols[1:])
        return cols

    def _sample_columns(self, blocks: list[tuple], cols: list[str]) -> dict[str, np.ndarray]:
        """Rows (step idx, n, BLOB per column) decoded into columns, ints as INT_SAMPLE_COLUMNS."""
        out = {"step_idx": np.repeat(np.array([b[0] for b in blocks], dtype=np.int64),
                                     [b[1] for b in blocks])}
        for i, c in enumerate(cols[1:], start=2):
            values = np.concatenate([self._decode(b[i], b[1], c) for b in blocks]) if blocks \
                else np.empty(0)
            if c in INT_SAMPLE_COLUMNS:
                values = np.where(np.isnan(values), MISSING_INT, values).astype(np.int64)
            out[c] = values
        return out

    def _decode(self, blob: bytes | None, n: int, column: str) -> np.ndarray:
        """One stored column block as float64 (an absent channel: NaN), its count and size
        checked before anything is allocated."""
        if isinstance(n, bool) or not isinstance(n, int) or not 0 <= n <= SAMPLES_PER_CHUNK:
            raise DataError(f"run database {self.path}: a block of column {column} claims "
                            f"{show(n)} samples (0 .. {SAMPLES_PER_CHUNK:,} allowed); the file "
                            "is damaged")
        if blob is None:
            return np.full(n, np.nan)
        if not isinstance(blob, bytes) or len(blob) != n * BLOB_DTYPE.itemsize:
            raise DataError(f"run database {self.path}: a block of column {column} holds "
                            f"{show(blob)} for {n} samples; the file is damaged")
        return np.frombuffer(blob, dtype=BLOB_DTYPE)

    def run_ids(self) -> list[str]:
        """Every run id, oldest first."""
        self._read.find_bad(None, "runs", ("id",), "1", ())
        return [self._run_id(r[0]) for r in self.conn.execute("SELECT id FROM runs ORDER BY id")]

    def runs(self, limit: int = 50) -> list[dict]:
        """The newest `limit` runs: id, name, status, created_utc, n_planned, command_unit and
        n_steps (stored points), each value checked."""
        names = ("id", "name", "status", "created_utc", "n_planned", "command_unit")
        self._read.find_bad(None, "runs", names, "1", ())
        return self._read.listing(
            f"SELECT {', '.join('r.' + n for n in names)}, "
            "(SELECT count(*) FROM steps s WHERE s.run_id = r.id) AS n_steps "
            "FROM runs r ORDER BY r.id DESC LIMIT ?", [limit])

    def steps(self, run_id: str) -> list[dict]:
        """A run's stored points, every column checked (counters_json as stored text)."""
        return self._step_rows(run_id, tuple(STEP_COLUMNS))

    def events(self, run_id: str, kind: str | None = None) -> list[dict]:
        """A run's events (of `kind`), oldest first, each `detail` parsed and checked."""
        where, args = "run_id = ?", [run_id]
        if kind:
            where += " AND kind = ?"
            args.append(kind)
        self._read.count(run_id, "events", where, args, MAX_STORED_EVENTS, "detail_json",
                         MAX_EVENT_BYTES)
        rows = list(self._read.rows(run_id, "events", tuple(EVENT_COLUMNS), where, args,
                                    "ORDER BY id"))
        for r in rows:
            r["detail"] = self._read.detail(run_id, r, r.pop("detail_json"))
        return rows

    def transport_counters(self, run_id: str) -> dict:
        """Transport counters summed over a run's stored points, and the points with problems.

        Returns {"totals": {role: {counter: n}}, "problem_points": [idx, ...]}, where a
        problem is any counter outside TRAFFIC_COUNTERS that moved during the point.
        """
        totals: dict[str, dict[str, int]] = {}
        problems = []
        rows = self._step_rows(run_id, ("idx", "counters_json"), " AND counters_json IS NOT NULL",
                               parse=True)
        for row in rows:
            bad = False
            for role, counters in row["counters_json"].items():
                into = totals.setdefault(role, {})
                for name, n in counters.items():
                    into[name] = into.get(name, 0) + n
                    bad = bad or (n > 0 and name not in TRAFFIC_COUNTERS)
            if bad:
                problems.append(row["idx"])
        return {"totals": totals, "problem_points": problems}

    def latest_calibration(self, run_id: str) -> dict | None:
        """The run's most recent calibration record (with its `state` blob, None for one
        stored before schema v6), or None when it was never calibrated."""
        names = ("id", "created_utc", "tool_version", "out_dir", "summary_json", "state")
        self._read.count(run_id, "calibrations", "run_id = ?", (run_id,),
                         MAX_STORED_CALIBRATIONS)
        rows = list(self._read.rows(run_id, "calibrations", names, "run_id = ?", (run_id,),
                                    "ORDER BY id DESC LIMIT 1"))
        if not rows:
            return None
        out = rows[0]
        out["summary"] = out.pop("summary_json")
        return out

    def check_run(self, run_id: str) -> None:
        """Check everything stored for a run, keeping nothing: DataError on the first bad value."""
        with self.snapshot():
            self.run(run_id)
            self._step_rows(run_id, tuple(STEP_COLUMNS))
            self.events(run_id)
            self.latest_calibration(run_id)
            self._read.check_blocks(run_id, "st.run_id = ?", (run_id,))

    def step_samples(self, step_id: int, columns: Iterable[str] = ("t_s", "thrust_n")
                     ) -> dict[str, np.ndarray]:
        """The samples of one stored point as float arrays (missing -> NaN), in time order."""
        cols = _checked_columns(columns)
        self._read.check_blocks(None, "b.step_id = ?", (step_id,))
        blocks = self.conn.execute(f"SELECT n, {', '.join(cols)} FROM sample_blocks WHERE "
                                   "step_id = ? ORDER BY chunk", (step_id,)).fetchall()
        return {c: np.concatenate([self._decode(b[i], b[0], c) for b in blocks])
                if blocks else np.empty(0) for i, c in enumerate(cols, start=1)}

    def samples(self, run_id: str, columns: Iterable[str] = SAMPLE_COLUMNS) -> dict[str, np.ndarray]:
        """All samples of a run as float arrays (missing -> NaN), in plan order, each point's
        in acquisition order; one snapshot, so a sweep appending points is not half seen.
        Every block's count and sizes are checked before the arrays are allocated."""
        cols = _checked_columns(columns)
        names = ["st.id" if c == "step_id" else "b." + c for c in cols]
        join = "FROM sample_blocks b JOIN steps st ON st.id = b.step_id WHERE st.run_id = ?"
        with self.snapshot():
            self._read.check_blocks(run_id, "st.run_id = ?", (run_id,))
            n = self.conn.execute(f"SELECT COALESCE(SUM(b.n), 0) {join}", (run_id,)).fetchone()[0]
            out = {c: np.empty(n) for c in cols}  # filled in place: 8 bytes per value, no copies
            cur = self.conn.execute(f"SELECT b.n, {', '.join(names)} {join} "
                                    "ORDER BY st.idx, b.chunk", (run_id,))
            filled = 0
            for row in cur:
                size = row[0]
                for i, c in enumerate(cols, start=1):
                    out[c][filled:filled + size] = (row[i] if c == "step_id"
                                                    else self._decode(row[i], size, c))
                filled += size
        return out


TABLES: dict[str, dict[str, Column]] = {
    "runs": RUN_COLUMNS, "steps": STEP_COLUMNS, "events": EVENT_COLUMNS,
    "calibrations": CALIBRATION_COLUMNS,
}
_ROW_KEYS = {"runs": ("id", "run"), "steps": ("idx", "point"), "events": ("id", "event"),
             "calibrations": ("id", "calibration")}
_BLOCK_OK = " AND ".join([
    f"typeof(st.idx) = 'integer' AND st.idx BETWEEN 0 AND {MAX_STORED_POINTS - 1}",
    f"typeof(b.n) = 'integer' AND b.n BETWEEN 0 AND {SAMPLES_PER_CHUNK}",
    f"typeof(b.chunk) = 'integer' AND b.chunk BETWEEN 0 AND {MAX_CHUNK}",
    "(b.n = 0 OR b.t_s IS NOT NULL)",
    *(f"(b.{c} IS NULL OR (typeof(b.{c}) = 'blob' AND length(b.{c}) = "
      f"{BLOB_DTYPE.itemsize} * b.n))" for c in SAMPLE_COLUMNS[1:])])


class _Reader:
    """Checked reads from one database: counts, types, ranges and lengths in SQL before
    anything is fetched, JSON texts parsed with bounds and checked for shape after. A
    failure is a DataError naming the database, the run and the field."""

    def __init__(self, conn: sqlite3.Connection, label: str) -> None:
        self.conn = conn
        self.label = label

    def damaged(self, run_id: object, where: str, problem: str) -> DataError:
        """The error for a stored value that fails its check."""
        run = "" if run_id is None else f"run {run_label(run_id)}, "
        return DataError(f"{self.label}: {run}{where}: {problem} (the database is damaged or "
                         "was edited)")

    def count(self, run_id: str, table: str, where: str, args: Sequence, cap: int,
              size_column: str | None = None, max_bytes: int = 0) -> None:
        """Refuse more than `cap` rows, or more than `max_bytes` in all in `size_column`."""
        n, size = self.conn.execute(f"SELECT count(*), total(length({size_column or 'NULL'})) "
                                    f"FROM {table} WHERE {where}", tuple(args)).fetchone()
        if n > cap:
            raise self.damaged(run_id, table, f"{n:,} rows; the limit is {cap:,}")
        if size_column and size > max_bytes:
            raise self.damaged(run_id, f"{table}.{size_column}",
                               f"{int(size):,} bytes in all; the limit is {max_bytes:,}")

    def find_bad(self, run_id: object, table: str, names: Sequence[str], where: str,
                 args: Sequence) -> None:
        """Refuse, before fetching it, a row with a value of the wrong type, range or length."""
        columns = TABLES[table]
        bad = [columns[n].bad_sql(n) for n in names]
        key = _ROW_KEYS[table][0]
        key_sql = f"substr({key}, 1, {MAX_ID_TEXT})" if table == "runs" else _probe(key)
        row = self.conn.execute(
            f"SELECT {', '.join(bad)}, rowid, {key_sql} FROM {table} "
            f"WHERE ({where}) AND ({' OR '.join(bad)}) LIMIT 1", tuple(args)).fetchone()
        if row is not None:
            name = names[row.index(1)]
            run_id = row[-1] if run_id is None and table == "runs" else run_id
            raise self.damaged(run_id, self._field(table, {key: row[-1]}, name),
                               self._problem(table, name, row[-2]))

    def _problem(self, table: str, name: str, rowid: int) -> str:
        """What is wrong with one stored value `find_bad` found, fetched only when small."""
        column = TABLES[table][name]
        size, value = self.conn.execute(
            f"SELECT length({name}), CASE WHEN length({name}) <= {column.length_cap()} THEN "
            f"{name} END FROM {table} WHERE rowid = ?", (rowid,)).fetchone()
        if size is not None and size > column.length_cap():
            if column.kind in ("int", "real"):
                return f"expected a number, found {size:,} characters or bytes"
            return f"{size:,} characters or bytes; the limit is {column.length_cap():,}"
        try:
            column.check(value)
        except Invalid as exc:
            return str(exc)
        return f"{show(value)} is not a value rigtool writes"

    def rows(self, run_id: object, table: str, names: Sequence[str], where: str,
             args: Sequence, order: str = "", parse: bool = True) -> Iterator[dict]:
        """The selected rows as checked dicts (JSON columns parsed when `parse`)."""
        columns = TABLES[table]
        self.find_bad(run_id, table, names, where, args)
        texts = [n for n in names if columns[n].kind == "json"]
        cur = self.conn.execute(f"SELECT {', '.join(names)} FROM {table} WHERE {where} {order}",
                                tuple(args))
        try:
            for values in cur:
                row = dict(zip(names, values, strict=True))
                for name in texts:
                    parsed = self._parsed(run_id, table, row, name)
                    if parse:
                        row[name] = parsed
                yield row
        except _NotUtf8 as exc:
            raise self.damaged(run_id, table, exc.problem) from None

    def _parsed(self, run_id: object, table: str, row: dict, name: str) -> Any:
        """A fetched JSON column parsed and checked against its shape."""
        try:
            return TABLES[table][name].check(row[name])
        except Invalid as exc:
            raise self.damaged(run_id, self._field(table, row, name), str(exc)) from None

    @staticmethod
    def _field(table: str, row: dict, name: str) -> str:
        """Where a value sits, for a message: `point 3, steps.command`."""
        key, label = _ROW_KEYS[table]
        if table == "runs" or key not in row:
            return f"{table}.{name}"
        return f"{label} {show(row[key])}, {table}.{name}"

    def listing(self, sql: str, args: Sequence) -> list[dict]:
        """Rows of a query over values already checked, as dicts keyed by column name."""
        try:
            cur = self.conn.execute(sql, tuple(args))
            names = [d[0] for d in cur.description]
            return [dict(zip(names, row, strict=True)) for row in cur]
        except _NotUtf8 as exc:
            raise self.damaged(None, "runs", exc.problem) from None

    def detail(self, run_id: str, row: dict, detail: Any) -> Any:
        """An event's parsed detail, checked against the shape its kind needs."""
        try:
            return event_detail(row["kind"], detail)
        except Invalid as exc:
            field = self._field("events", row, "detail_json")
            raise self.damaged(run_id, field, str(exc)) from None

    def check_blocks(self, run_id: str | None, where: str, args: Sequence) -> None:
        """Refuse, before any is decoded, a selected block of a bad count, number or size."""
        row = self.conn.execute(
            "SELECT b.id, substr(st.run_id, 1, ?) FROM sample_blocks b JOIN steps st "
            f"ON st.id = b.step_id WHERE ({where}) AND NOT ({_BLOCK_OK}) LIMIT 1",
            (MAX_ID_TEXT, *args)).fetchone()
        if row is not None:
            raise self.damaged(row[1] if run_id is None else run_id, *self._block_problem(row[0]))

    def _block_problem(self, block_id: int) -> tuple[str, str]:
        """(where, problem) of a block `check_blocks` refused."""
        probes = ", ".join(f"typeof(b.{c}), length(b.{c})" for c in SAMPLE_COLUMNS[1:])
        idx, n, chunk, *sizes = self.conn.execute(
            f"SELECT {_probe('st.idx')}, {_probe('b.n')}, {_probe('b.chunk')}, {probes} "
            "FROM sample_blocks b JOIN steps st ON st.id = b.step_id WHERE b.id = ?",
            (block_id,)).fetchone()
        point = f"point {show(idx)}, block {show(chunk)}"
        for name, value, hi in (("steps.idx", idx, MAX_STORED_POINTS - 1),
                                ("sample_blocks.n", n, SAMPLES_PER_CHUNK),
                                ("sample_blocks.chunk", chunk, MAX_CHUNK)):
            try:
                Column("int", lo=0, hi=hi).check(value)
            except Invalid as exc:
                return f"{point}, {name}", str(exc)
        for c, kind, size in zip(SAMPLE_COLUMNS[1:], sizes[::2], sizes[1::2], strict=True):
            if kind == "null" and c == "t_s" and n > 0:
                return f"{point}, sample_blocks.t_s", f"missing for n = {n:,} samples"
            if kind not in ("null", "blob"):
                return f"{point}, sample_blocks.{c}", f"expected a blob, found {kind}"
            if kind == "blob" and size != BLOB_DTYPE.itemsize * n:
                return (f"{point}, sample_blocks.{c}",
                        f"{size:,} bytes for n = {n:,} samples of {BLOB_DTYPE.itemsize} bytes")
        return point, "not a block rigtool writes"


class _NotUtf8(DataError):
    """A stored text that is not UTF-8, met while a row is fetched."""

    def __init__(self, label: str, raw: bytes) -> None:
        self.problem = f"a text is not UTF-8 ({show(raw)})"
        super().__init__(f"{label}: {self.problem} (the database is damaged or was edited)")


def _utf8_text(label: str) -> Callable[[bytes], str]:
    """A connection's text factory: UTF-8, and a DataError for anything else."""
    def decode(raw: bytes) -> str:
        """`raw` as UTF-8 text."""
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            raise _NotUtf8(label, raw) from None
    return decode


def _probe(column: str) -> str:
    """SQL giving a column's number as it is, anything else as a short text."""
    return (f"CASE WHEN typeof({column}) IN ('integer', 'real') THEN {column} "
            f"ELSE typeof({column}) || ' ' || quote(substr({column}, 1, 20)) END")


class _MergeSource:
    """A run database to merge from: opened read-only, checked to have exactly rigtool's
    schema, read through explicit column lists, every row checked before it is copied."""

    def __init__(self, path: Path, version: int) -> None:
        self.path = path
        self.conn = _open_source(path)
        self.read = _Reader(self.conn, f"merge source {path}")
        try:
            self._check_schema(version)
        except BaseException:
            self.conn.close()
            raise

    def close(self) -> None:
        """Close the source; it was never written to."""
        self.conn.close()

    def _check_schema(self, version: int) -> None:
        """Refuse another schema version, a view, a trigger, or any table not rigtool's."""
        try:
            found = self.conn.execute("PRAGMA user_version").fetchone()[0]
            problem = _schema_difference(self.conn)
        except sqlite3.DatabaseError as exc:
            raise DataError(f"merge source {self.path}: not a readable SQLite database "
                            f"({exc})") from None
        if found != version:
            raise UsageError(f"{self.path} has schema version {found}, this store {version}: "
                             "open both with the same rigtool first (a writing command such as "
                             "`rigtool calibrate` upgrades an older store)")
        if problem:
            raise DataError(f"merge source {self.path}: {problem}; only the tables rigtool "
                            "makes are merged")

    def copy_into(self, into: _Reader, here: set[str]) -> MergeReport:
        """Merge every finished run into the target `into` reads (in its transaction)."""
        report = MergeReport()
        run_id = None
        self.conn.execute("BEGIN")
        try:
            for run_id in self._run_ids():
                self._merge_run(into, run_id, here, report)
        except sqlite3.IntegrityError as exc:
            raise self.read.damaged(run_id, "copying it", str(exc)) from None
        except sqlite3.OperationalError:
            raise
        except sqlite3.DatabaseError as exc:
            raise DataError(f"merge source {self.path}: cannot be read ({exc})") from None
        finally:
            self.conn.execute("ROLLBACK")
        return report

    def _run_ids(self) -> list[str]:
        """The source's run ids, each in the run-id grammar (it names output folders)."""
        self.read.count(None, "runs", "1", (), MAX_MERGE_RUNS)
        self.read.find_bad(None, "runs", ("id",), "1", ())
        ids = [r[0] for r in self.conn.execute("SELECT id FROM runs ORDER BY id")]
        for run_id in ids:
            if not is_run_id(run_id):
                raise self.read.damaged(run_id, "runs.id", "not a run id rigtool makes "
                                        "(YYYYMMDDThhmmssmmmZ-xxxxxx)")
        return ids

    def _merge_run(self, into: _Reader, run_id: str, here: set[str], report: MergeReport
                   ) -> None:
        """Add a run the target lacks, or bring what is new of one it has; file the outcome."""
        (run,) = self.read.rows(run_id, "runs", tuple(RUN_COLUMNS), "id = ?", (run_id,),
                                parse=False)
        if run["status"] == "running":
            report.running.append(run_id)
            return
        change = RunChange(run_id)
        if run_id not in here:
            _insert(into.conn, "runs", run)
            here.add(run_id)
            self._merge_contents(into, run_id, change)
            report.added.append(run_id)
            return
        (mine,) = into.rows(run_id, "runs", tuple(RUN_COLUMNS), "id = ?", (run_id,),
                            parse=False)
        if mine["status"] == "running":
            report.busy.append(run_id)
            return
        self._merge_record(into, run, mine, change)
        self._merge_contents(into, run_id, change)
        if change.changed:
            report.updated.append(change)
        else:
            report.present.append(run_id)

    def _conflict(self, into: _Reader, run_id: str, where: str, problem: str) -> MergeConflict:
        """The error for a run whose two copies disagree on something both hold."""
        return MergeConflict(f"merge source {self.path}: run {run_label(run_id)}, {where}: "
                             f"{problem} (the two copies of the run disagree, and {into.label} "
                             "is not overwritten)")

    def _merge_record(self, into: _Reader, run: dict, mine: dict, change: RunChange) -> None:
        """Take the source's status, finish and resume time when its run ended later."""
        for name in RUN_COLUMNS:
            if name not in MERGE_MUTABLE and run[name] != mine[name]:
                raise self._conflict(into, run["id"], f"runs.{name}",
                                     f"{show(run[name])} here, {show(mine[name])} there")
        if _run_time(run) < _run_time(mine):
            return
        differ = [name for name in MERGE_MUTABLE if run[name] != mine[name]]
        if not differ:
            return
        if _run_time(run) == _run_time(mine):
            raise self._conflict(into, run["id"], f"runs.{differ[0]}",
                                 f"{show(run[differ[0]])} here, {show(mine[differ[0]])} there, "
                                 "for the same start and end time")
        into.conn.execute(f"UPDATE main.runs SET {', '.join(n + ' = ?' for n in MERGE_MUTABLE)} "
                          "WHERE id = ? AND status != 'running'",
                          (*(run[n] for n in MERGE_MUTABLE), run["id"]))
        change.record = True
        if run["status"] != mine["status"]:
            change.status = (mine["status"], run["status"])

    def _merge_contents(self, into: _Reader, run_id: str, change: RunChange) -> None:
        """The run's points, samples, calibrations and events the target lacks."""
        change.points = self._merge_points(into, run_id)
        newer = self._merge_calibrations(into, run_id, change)
        self._merge_events(into, run_id, newer, change)

    def _merge_points(self, into: _Reader, run_id: str) -> int:
        """Insert the points the target lacks; a point both hold must be the same. Returns
        how many were inserted."""
        self.read.count(run_id, "steps", "run_id = ?", (run_id,), MAX_STORED_POINTS)
        theirs = {row["idx"]: _digest(_point_fields(row)) for row in into.rows(
            run_id, "steps", tuple(STEP_COLUMNS), "run_id = ?", (run_id,), parse=False)}
        new: dict[int, int] = {}
        sizes: dict[int, int] = {}
        for step in self.read.rows(run_id, "steps", tuple(STEP_COLUMNS), "run_id = ?",
                                   (run_id,), "ORDER BY idx", parse=False):
            sizes[step["idx"]] = step["n"]
            if step["idx"] not in theirs:
                new[step["idx"]] = _insert(into.conn, "steps", step, skip="id")
            elif theirs[step["idx"]] != _digest(_point_fields(step)):
                raise self._point_conflict(into, step)
        self._merge_blocks(into, run_id, new, sizes)
        return len(new)

    def _point_conflict(self, into: _Reader, step: dict) -> MergeConflict:
        """The error for a point whose stored fields differ from the target's."""
        (mine,) = into.rows(step["run_id"], "steps", tuple(STEP_COLUMNS),
                            "run_id = ? AND idx = ?", (step["run_id"], step["idx"]), parse=False)
        name = next(n for n in STEP_COLUMNS if n != "id" and step[n] != mine[n])
        return self._conflict(into, step["run_id"], f"point {step['idx']}, steps.{name}",
                              f"{show(step[name])} here, {show(mine[name])} there")

    def _merge_blocks(self, into: _Reader, run_id: str, new: dict[int, int],
                      sizes: dict[int, int]) -> None:
        """Copy the blocks of the `new` points (idx -> target step id), each adding up to
        its `n`; the blocks of every other point must hash as the target's do."""
        self.read.check_blocks(run_id, "st.run_id = ?", (run_id,))
        held = dict.fromkeys(sizes, 0)
        ours: dict[int, Any] = {}
        for idx, chunk, n, *values in self.conn.execute(BLOCKS_OF_RUN, (run_id,)):
            held[idx] += n
            if idx in new:
                into.conn.execute(INSERT_BLOCK, (new[idx], chunk, n, *values))
            else:
                _feed(ours.setdefault(idx, hashlib.sha256()), (chunk, n, *values))
        for idx, n in sizes.items():
            if held[idx] != n:
                raise self.read.damaged(run_id, f"point {idx}, steps.n",
                                        f"{n:,} samples, but its blocks hold {held[idx]:,}")
        if len(new) < len(sizes):
            theirs = _block_digests(into.conn, run_id)
            for idx in sorted(set(sizes) - set(new)):
                if _hexdigest(ours.get(idx)) != _hexdigest(theirs.get(idx)):
                    raise self._conflict(into, run_id, f"point {idx}, sample_blocks",
                                         "its samples differ from those there")

    def _merge_calibrations(self, into: _Reader, run_id: str, change: RunChange) -> bool:
        """Insert the calibrations the target lacks; whether the source's newest is newer
        than every one the target had."""
        self.read.count(run_id, "calibrations", "run_id = ?", (run_id,),
                        MAX_STORED_CALIBRATIONS)
        theirs: Counter[bytes] = Counter()
        newest_theirs = ""
        for cal in into.rows(run_id, "calibrations", CALIBRATION_KEY, "run_id = ?", (run_id,),
                             parse=False):
            theirs[_digest(cal.values())] += 1
            newest_theirs = max(newest_theirs, cal["created_utc"])
        newest_ours = ""
        for cal in self.read.rows(run_id, "calibrations", tuple(CALIBRATION_COLUMNS),
                                  "run_id = ?", (run_id,), "ORDER BY id", parse=False):
            newest_ours = max(newest_ours, cal["created_utc"])
            key = _digest(cal[n] for n in CALIBRATION_KEY)
            if theirs[key]:
                theirs[key] -= 1
                continue
            _insert(into.conn, "calibrations", cal, skip="id")
            change.calibrations += 1
        return newest_ours > newest_theirs

    def _events(self, run_id: str) -> Iterator[dict]:
        """The run's events, each checked (its detail against its kind's shape)."""
        for event in self.read.rows(run_id, "events", tuple(EVENT_COLUMNS), "run_id = ?",
                                    (run_id,), "ORDER BY id", parse=False):
            self.read.detail(run_id, event, EVENT_COLUMNS["detail_json"].check(
                event["detail_json"]))
            yield event

    def _merge_events(self, into: _Reader, run_id: str, newer: bool, change: RunChange
                      ) -> None:
        """Insert the events the target lacks. A kind the target holds events of that the
        source does not was rewritten by a calibration (ventilation): the side with the
        newest calibration keeps its events of that kind."""
        self.read.count(run_id, "events", "run_id = ?", (run_id,), MAX_STORED_EVENTS,
                        "detail_json", MAX_EVENT_BYTES)
        theirs = _event_digests(into, run_id)
        ours: dict[str, Counter[bytes]] = {}
        for event in self._events(run_id):
            ours.setdefault(event["kind"], Counter())[_digest(_event_key(event))] += 1
        rewritten = {k for k, held in theirs.items() if held - ours.get(k, Counter())}
        for kind in rewritten if newer else ():
            into.conn.execute("DELETE FROM main.events WHERE run_id = ? AND kind = ?",
                              (run_id, kind))
            change.events_replaced += sum(theirs.pop(kind).values())
        wanted = {k: held - theirs.get(k, Counter()) for k, held in ours.items()
                  if newer or k not in rewritten}
        for event in self._events(run_id) if any(wanted.values()) else ():
            key = _digest(_event_key(event))
            if wanted.get(event["kind"], Counter())[key] > 0:
                wanted[event["kind"]][key] -= 1
                _insert(into.conn, "events", event, skip="id")
                change.events += 1


MERGE_MUTABLE = ("status", "finished_utc", "stop_reason", "started_utc", "host", "pid")
CALIBRATION_KEY = ("created_utc", "tool_version", "out_dir", "summary_json", "state")
BLOCKS_OF_RUN = (f"SELECT st.idx, b.chunk, b.n, {', '.join('b.' + c for c in SAMPLE_COLUMNS[1:])} "
                 "FROM sample_blocks b JOIN steps st ON st.id = b.step_id WHERE st.run_id = ? "
                 "ORDER BY st.idx, b.chunk")


class MergeConflict(DataError):
    """Two copies of a run disagree on something both hold; nothing is merged."""


@dataclass
class RunChange:
    """What a merge brought to one run: points, run record, calibrations and events."""

    run_id: str
    points: int = 0
    status: tuple[str, str] | None = None  # (before, after) when the status changed
    record: bool = False  # status, finish or resume time taken from the source
    calibrations: int = 0
    events: int = 0
    events_replaced: int = 0  # events of a kind a newer calibration rewrote

    @property
    def changed(self) -> bool:
        """Whether the merge changed anything of the run."""
        return any((self.points, self.record, self.calibrations, self.events,
                    self.events_replaced))

    def describe(self) -> str:
        """One line: `+3 point(s), status interrupted -> completed, +1 calibration(s)`."""
        parts = [f"+{self.points} point(s)"] if self.points else []
        if self.status:
            parts.append(f"status {self.status[0]} -> {self.status[1]}")
        elif self.record:
            parts.append("run record updated (resumed)")
        parts += [f"+{n} {what}" for n, what in ((self.calibrations, "calibration(s)"),
                                                   (self.events, "event(s)")) if n]
        if self.events_replaced:
            parts.append(f"{self.events_replaced} event(s) of an older calibration replaced")
        return ", ".join(parts)


@dataclass
class MergeReport:
    """What merging one source did, by run id."""

    added: list[str] = field(default_factory=list)
    updated: list[RunChange] = field(default_factory=list)
    present: list[str] = field(default_factory=list)  # nothing new in the source
    running: list[str] = field(default_factory=list)  # still running in the source
    busy: list[str] = field(default_factory=list)  # running in the target: left alone


def _run_time(run: dict) -> tuple[str, str]:
    """When a run was last started and when it ended: the later copy of a run is ahead."""
    return run["started_utc"] or "", run["finished_utc"] or ""


def _point_fields(step: dict) -> list:
    """A stored point's values but its row id and run id, in STEP_COLUMNS order."""
    return [step[n] for n in STEP_COLUMNS if n not in ("id", "run_id")]


def _event_key(event: dict) -> list:
    """What identifies an event across copies of a run (its row id does not)."""
    return [event["kind"], event["t_s"], event["step_idx"], event["detail_json"]]


def _feed(digest: Any, values: Iterable[object]) -> None:
    """Add SQL values to a hash, tagged by type and length so no two rows collide."""
    for value in values:
        if value is None:
            digest.update(b"n;")
        elif isinstance(value, bytes):
            digest.update(b"b%d;" % len(value))
            digest.update(value)
        elif isinstance(value, str):
            data = value.encode("utf-8")
            digest.update(b"s%d;" % len(data))
            digest.update(data)
        else:
            digest.update(f"{type(value).__name__}:{value!r};".encode())


def _digest(values: Iterable[object]) -> bytes:
    """The SHA-256 of a row's values."""
    digest = hashlib.sha256()
    _feed(digest, values)
    return digest.digest()


def _hexdigest(digest: Any) -> str | None:
    """A running hash's value (None: no blocks)."""
    return None if digest is None else digest.hexdigest()


def _block_digests(conn: sqlite3.Connection, run_id: str) -> dict[int, Any]:
    """Per point of a run in `conn`, the hash of its blocks in chunk order."""
    out: dict[int, Any] = {}
    for idx, *values in conn.execute(BLOCKS_OF_RUN, (run_id,)):
        _feed(out.setdefault(idx, hashlib.sha256()), values)
    return out


def _event_digests(read: _Reader, run_id: str) -> dict[str, Counter[bytes]]:
    """Per kind, how many of each event a run holds, by hash."""
    out: dict[str, Counter[bytes]] = {}
    for event in read.rows(run_id, "events", tuple(EVENT_COLUMNS), "run_id = ?", (run_id,),
                           parse=False):
        out.setdefault(event["kind"], Counter())[_digest(_event_key(event))] += 1
    return out


def _insert(conn: sqlite3.Connection, table: str, row: dict, skip: str = "") -> int:
    """Insert a checked row into `main.table` by explicit columns; the new row id."""
    names = [k for k in row if k != skip]
    cur = conn.execute(f"INSERT INTO main.{table} ({', '.join(names)}) VALUES "
                       f"({', '.join('?' * len(names))})", [row[k] for k in names])
    return cur.lastrowid


def _open_source(path: Path) -> sqlite3.Connection:
    """`path` read-only, query-only, and immutable unless its -wal holds commits."""
    if not path.is_file():
        raise UsageError(f"no run database at {path}")
    wal = path.with_name(path.name + "-wal")
    live = wal.exists() and wal.stat().st_size > 0
    uri = path.resolve().as_uri() + ("?mode=ro" if live else "?mode=ro&immutable=1")
    try:
        conn = sqlite3.connect(uri, uri=True, isolation_level=None)
        conn.text_factory = _utf8_text(f"merge source {path}")
        conn.execute("PRAGMA query_only = ON")
        conn.execute("PRAGMA trusted_schema = OFF")
    except sqlite3.Error as exc:
        raise DataError(f"merge source {path}: cannot be opened ({exc})") from None
    return conn


_SCHEMA_OBJECTS = ("SELECT type, name, tbl_name FROM sqlite_master WHERE NOT (type = 'table' "
                   "AND name LIKE 'sqlite\\_%' ESCAPE '\\') LIMIT 1000")


@functools.cache
def _expected_schema() -> tuple[frozenset, dict[str, list]]:
    """The schema objects and table columns of a store this rigtool creates."""
    conn = sqlite3.connect(":memory:")
    try:
        create_schema(conn)
        objects = frozenset(conn.execute(_SCHEMA_OBJECTS).fetchall())
        return objects, {t: _table_info(conn, t) for t in (*TABLES, "sample_blocks")}
    finally:
        conn.close()


def _table_info(conn: sqlite3.Connection, table: str) -> list:
    """A table's columns, and its kind (a WITHOUT ROWID or STRICT table is not rigtool's)."""
    kind = conn.execute("SELECT type, wr, strict FROM pragma_table_list WHERE schema = 'main' "
                        "AND name = ?", (table,)).fetchall()
    return [*kind, *conn.execute(f"PRAGMA main.table_info({table})").fetchall()]


def _schema_difference(conn: sqlite3.Connection) -> str | None:
    """What sets a database's schema apart from rigtool's (None: nothing)."""
    objects, columns = _expected_schema()
    found = set(conn.execute(_SCHEMA_OBJECTS).fetchall())
    if len(found) >= 1000:
        return "it has 1,000 or more tables, views, indexes or triggers"
    extra = sorted(found - objects, key=lambda o: (o[0] not in ("view", "trigger"), str(o)))
    missing = sorted(objects - found)
    if extra:
        return f"it has a {extra[0][0]} {show(extra[0][1])} that rigtool does not make"
    if missing:
        return f"it has no {missing[0][0]} {missing[0][1]}"
    for table, expected in columns.items():
        if _table_info(conn, table) != expected:
            return f"its table {table} has other columns than rigtool's"
    return None


INSERT_BLOCK = (f"INSERT INTO sample_blocks (step_id, chunk, n, {', '.join(SAMPLE_COLUMNS[1:])}) "
                f"VALUES (?, ?, ?{', ?' * (len(SAMPLE_COLUMNS) - 1)})")


def _encode(values: np.ndarray | None) -> bytes | None:
    """A column block as little-endian float64 bytes; None (NULL) when it holds no value."""
    if values is None:
        return None
    array = np.ascontiguousarray(values, dtype=BLOB_DTYPE)
    return None if np.isnan(array).all() else array.tobytes()


def _block_row(step_id: int, chunk: int, columns: dict[str, np.ndarray | None]) -> tuple:
    """The INSERT_BLOCK parameters of one block of a point's samples (t_s is required)."""
    n = len(columns["t_s"])
    return (step_id, chunk, n, *(_encode(columns.get(c)) for c in SAMPLE_COLUMNS[1:]))


SAMPLE_BLOCKS_SCHEMA = f"""
CREATE TABLE sample_blocks (
    id INTEGER PRIMARY KEY,
    step_id INTEGER NOT NULL REFERENCES steps(id),
    chunk INTEGER NOT NULL,
    n INTEGER NOT NULL,
    {', '.join(c + ' BLOB' for c in SAMPLE_COLUMNS[1:])},
    UNIQUE (step_id, chunk)
)
"""


def _samples_to_blocks(conn: sqlite3.Connection) -> None:
    """Migration v8: every point's sample rows become column blocks; the rows table goes.

    Each point is read in SAMPLES_PER_CHUNK rows at a time, so memory stays bounded; the
    freed pages are reused by later runs (VACUUM returns them to the disk)."""
    conn.execute(SAMPLE_BLOCKS_SCHEMA)
    cols = SAMPLE_COLUMNS[1:]
    for (step_id,) in conn.execute("SELECT id FROM steps ORDER BY id").fetchall():
        cur = conn.execute(f"SELECT {', '.join(cols)} FROM samples WHERE step_id = ? "
                           "ORDER BY rowid", (step_id,))
        chunk = 0
        while rows := cur.fetchmany(SAMPLES_PER_CHUNK):
            data = np.array(rows, dtype=float).reshape(len(rows), len(cols))
            conn.execute(INSERT_BLOCK, _block_row(step_id, chunk, {
                c: data[:, i] for i, c in enumerate(cols)}))
            chunk += 1
    conn.execute("DROP TABLE samples")


def _opt_float(value: object) -> float | None:
    return None if value is None else float(value)  # type: ignore[arg-type]


def _checked_columns(columns: Iterable[str]) -> list[str]:
    cols = list(columns)
    bad = set(cols) - set(SAMPLE_COLUMNS)
    if bad:
        raise ValueError(f"unknown sample columns {sorted(bad)}")
    return cols


class _Transaction:
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
        try:
            self.conn.execute("BEGIN IMMEDIATE")
        except sqlite3.OperationalError as exc:
            raise self._explain(exc) from exc
        return self.conn

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


def segment_stats(values: np.ndarray | None, bounds: np.ndarray) -> dict[str, list]:
    """mean, std (ddof 1; 0 for one value), min and max of the finite values of each segment
    values[bounds[i]:bounds[i + 1]] (None where a segment has none), as `_stats` per point."""
    n_seg = len(bounds) - 1
    if values is None or n_seg == 0:
        return {k: [None] * n_seg for k in ("mean", "std", "min", "max")}
    v = np.asarray(values, dtype=float)
    starts = np.asarray(bounds[:-1], dtype=np.int64)
    seg = np.repeat(np.arange(n_seg), np.diff(bounds))
    finite = np.isfinite(v)
    count = np.bincount(seg, weights=finite, minlength=n_seg)
    good = np.where(finite, v, 0.0)
    mean = np.bincount(seg, weights=good, minlength=n_seg) / np.maximum(count, 1)
    dev = np.where(finite, v - mean[seg], 0.0)
    var = np.bincount(seg, weights=dev * dev, minlength=n_seg) / np.maximum(count - 1, 1)
    std = np.where(count > 1, np.sqrt(var), 0.0)
    low = np.minimum.reduceat(np.where(finite, v, np.inf), starts)
    high = np.maximum.reduceat(np.where(finite, v, -np.inf), starts)
    out = {}
    for key, arr in (("mean", mean), ("std", std), ("min", low), ("max", high)):
        obj = arr.astype(object)
        obj[count == 0] = None
        out[key] = obj.tolist()
    return out
