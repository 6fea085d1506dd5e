"""SQLite run store: schema, migrations, the single writer, and queries.

Fixed tables (runs, steps, samples, events, calibrations) in WAL mode; the schema
version lives in PRAGMA user_version. Samples are inserted with the step they
belong to in one transaction, so a crash never leaves half a point.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import logging
import os
import secrets
import socket
import sqlite3
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
import sqlite_utils

from rigtool.errors import StoreError, UsageError
from rigtool.spool import SampleSpool

log = logging.getLogger(__name__)

DB_ENV = "RIGTOOL_DB"
DEFAULT_DB = "rigtool.sqlite"

RUN_STATUSES = ("running", "completed", "aborted", "failed", "interrupted")

SAMPLE_COLUMNS = (
    "step_id", "t_s", "fx", "fy", "fz", "tx", "ty", "tz",
    "thrust_n", "speed_rpm", "current_a", "voltage_v", "command", "seq",
)

STAT_FIELDS = ("thrust_n", "speed_rpm", "current_a")

# Bulk writes (imports): sample rows per executemany call, and per transaction, so a big
# import holds the write lock for about a second at a time and never builds all rows at once.
BATCH_ROWS = 10_000
IMPORT_ROWS_PER_TRANSACTION = 200_000

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


def resolve_db_path(cli_value: str | None, rig_value: str | None = None) -> Path:
    """DB path from --db, then $RIGTOOL_DB, then the rig file, then ./rigtool.sqlite."""
    return Path(cli_value or os.environ.get(DB_ENV) or rig_value or DEFAULT_DB)


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
            self.db = sqlite_utils.Database(self.conn)
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
        host = socket.gethostname()
        try:
            rows = self.conn.execute(
                "SELECT id, host, pid FROM runs WHERE status = 'running'").fetchall()
        except sqlite3.DatabaseError:
            return
        dead = [run_id for run_id, run_host, pid in rows
                if run_host == host and not _pid_alive(pid)]
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
        first, even while a sweep appends points. Nested use joins the outer snapshot."""
        if self.conn.in_transaction:
            yield
            return
        self.conn.execute("BEGIN")
        try:
            yield
        finally:
            if self.conn.in_transaction:
                self.conn.execute("COMMIT")

    def transaction(self) -> _Transaction:
        """Context manager: BEGIN IMMEDIATE ... COMMIT, or ROLLBACK on error."""
        return _Transaction(self.conn, self.path)

    def close(self) -> None:
        self.conn.close()

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
        with self.transaction():
            self.db["runs"].insert(row)
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
            for rows in spool.row_blocks():
                # SQLite stores a bound NaN as NULL, so missing channels read back as NULL.
                self.conn.executemany(
                    f"INSERT INTO samples ({', '.join(SAMPLE_COLUMNS)}) "
                    f"VALUES ({', '.join('?' * len(SAMPLE_COLUMNS))})",
                    ((step_id, *r) for r in rows.tolist()),
                )
        return step_id

    def add_points(self, run_id: str, points: dict[str, np.ndarray], bounds: np.ndarray,
                   samples: dict[str, np.ndarray], command_unit: str) -> None:
        """Insert many finished points (idx 0, 1, ...) with their samples, for imports.

        Point i owns samples[c][bounds[i]:bounds[i + 1]]; `points` holds the StepRecord fields
        command, depth_m (NaN = none), repeat, direction, t_*_s, settle_s and rate_hz as
        arrays. Rows go in with executemany in batches of BATCH_ROWS, in transactions of at most
        IMPORT_ROWS_PER_TRANSACTION sample rows (one point never splits).
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
        step_ids = np.repeat(np.arange(first_id, first_id + stop - start),
                             np.diff(bounds[start:stop + 1]))
        sql = (f"INSERT INTO samples ({', '.join(SAMPLE_COLUMNS)}) "
               f"VALUES ({', '.join('?' * len(SAMPLE_COLUMNS))})")
        lo = int(bounds[start])
        for a in range(lo, int(bounds[stop]), BATCH_ROWS):
            b = min(int(bounds[stop]), a + BATCH_ROWS)
            matrix = np.empty((b - a, len(SAMPLE_COLUMNS)))
            matrix[:, 0] = step_ids[a - lo:b - lo]
            for i, c in enumerate(SAMPLE_COLUMNS[1:], start=1):
                values = samples.get(c)
                matrix[:, i] = np.nan if values is None else values[a:b]
            # SQLite stores a bound NaN as NULL, so missing channels read back as NULL.
            self.conn.executemany(sql, matrix.tolist())

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

    def add_calibration(self, run_id: str, out_dir: str, summary: dict, tool_version: str) -> None:
        with self.transaction():
            self.db["calibrations"].insert({
                "run_id": run_id, "created_utc": utc_now(), "tool_version": tool_version,
                "out_dir": out_dir, "summary_json": json.dumps(summary),
            })

    # -- reading --------------------------------------------------------------------------
    def resolve_run_id(self, ref: str) -> str:
        """Accept a full id, an unambiguous literal id prefix, or `last`: the run most
        recently started or resumed. An empty or blank reference matches nothing."""
        if not ref.strip():
            raise UsageError(f"empty run id {ref!r}: give a run id, a prefix of one, or `last`")
        if ref == "last":
            row = self.conn.execute(
                "SELECT id FROM runs ORDER BY started_utc DESC, id DESC LIMIT 1").fetchone()
            if row is None:
                raise UsageError(f"no runs in {self.path} yet: run `rigtool sweep` first")
            return row[0]
        rows = self.conn.execute(
            "SELECT id FROM runs WHERE substr(id, 1, ?) = ? ORDER BY id", (len(ref), ref)
        ).fetchall()
        if not rows:
            raise UsageError(f"no run {ref!r} in {self.path} (see `rigtool runs`)")
        if len(rows) > 1:
            raise UsageError(f"run id prefix {ref!r} is ambiguous: {', '.join(r[0] for r in rows[:5])}")
        return rows[0][0]

    def run(self, run_id: str) -> dict:
        row = self.db["runs"].get(run_id)
        out = dict(row)
        for key in ("protocol_json", "rig_json", "plan_json", "metadata_json"):
            out[key.removesuffix("_json")] = json.loads(out.pop(key))
        actuator = out.pop("actuator_json")
        out["actuator"] = None if actuator is None else json.loads(actuator)
        return out

    def runs(self, limit: int = 50) -> list[dict]:
        return list(self.db.query(
            "SELECT r.id, r.name, r.status, r.created_utc, r.n_planned, r.command_unit, "
            "(SELECT count(*) FROM steps s WHERE s.run_id = r.id) AS n_steps "
            "FROM runs r ORDER BY r.id DESC LIMIT ?", [limit]))

    def steps(self, run_id: str) -> list[dict]:
        return list(self.db.query("SELECT * FROM steps WHERE run_id = ? ORDER BY idx", [run_id]))

    def events(self, run_id: str, kind: str | None = None) -> list[dict]:
        sql = "SELECT * FROM events WHERE run_id = ?"
        args: list[Any] = [run_id]
        if kind:
            sql += " AND kind = ?"
            args.append(kind)
        rows = list(self.db.query(sql + " ORDER BY id", args))
        for r in rows:
            r["detail"] = json.loads(r.pop("detail_json"))
        return rows

    def transport_counters(self, run_id: str) -> dict:
        """Transport counters summed over a run's stored points, and the points with problems.

        Returns {"totals": {role: {counter: n}}, "problem_points": [idx, ...]}, where a
        problem is any counter outside TRAFFIC_COUNTERS that moved during the point.
        """
        totals: dict[str, dict[str, int]] = {}
        problems = []
        rows = self.conn.execute("SELECT idx, counters_json FROM steps WHERE run_id = ? "
                                 "AND counters_json IS NOT NULL ORDER BY idx", (run_id,))
        for idx, text in rows:
            bad = False
            for role, counters in json.loads(text).items():
                into = totals.setdefault(role, {})
                for name, n in counters.items():
                    into[name] = into.get(name, 0) + n
                    bad = bad or (n > 0 and name not in TRAFFIC_COUNTERS)
            if bad:
                problems.append(idx)
        return {"totals": totals, "problem_points": problems}

    def samples(self, run_id: str, columns: Iterable[str] = SAMPLE_COLUMNS) -> dict[str, np.ndarray]:
        """All samples of a run as float arrays (NULL -> NaN), ordered by step then time."""
        cols = list(columns)
        bad = set(cols) - set(SAMPLE_COLUMNS)
        if bad:
            raise ValueError(f"unknown sample columns {sorted(bad)}")
        cur = self.conn.execute(
            f"SELECT {', '.join('s.' + c for c in cols)} FROM samples s "
            "JOIN steps st ON st.id = s.step_id WHERE st.run_id = ? ORDER BY s.rowid",
            (run_id,),
        )
        rows = cur.fetchall()
        if not rows:
            return {c: np.empty(0) for c in cols}
        data = np.array(rows, dtype=float)
        return {c: data[:, i] for i, c in enumerate(cols)}


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
