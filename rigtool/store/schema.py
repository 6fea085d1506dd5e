"""The schema of a run database and its migrations, each a named function taking the store
from one version to the next; the version lives in PRAGMA user_version.

Fixed tables (runs, steps, sample_blocks, events, calibrations). MIGRATIONS[v] takes a store
from version v to v + 1, one transaction each; `schema_difference` tells a database whose
tables are not exactly these (a merge source) apart.
"""

from __future__ import annotations

import functools
import sqlite3
from collections.abc import Callable
from pathlib import Path

import numpy as np

from rigtool.errors import DataError, StoreError
from rigtool.readback import show
from rigtool.spool import SAMPLES_PER_CHUNK
from rigtool.store.codec import SAMPLE_COLUMNS, block_row
from rigtool.store.connection import Transaction
from rigtool.store.records import POINT_STATS, STAT_FIELDS, stat_column

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

INSERT_BLOCK = (f"INSERT INTO sample_blocks (step_id, chunk, n, {', '.join(SAMPLE_COLUMNS[1:])}) "
                f"VALUES (?, ?, ?{', ?' * (len(SAMPLE_COLUMNS) - 1)})")

# The tables rigtool makes, in the order a schema difference is looked for.
TABLES = ("runs", "steps", "events", "calibrations", "sample_blocks")


def _execute_script(conn: sqlite3.Connection, script: str) -> None:
    """Run `;`-separated DDL inside the caller's transaction (executescript would commit)."""
    for statement in script.split(";"):
        if statement.strip():
            conn.execute(statement)


def migrate_0_to_1(conn: sqlite3.Connection) -> None:
    """v1: runs, steps, one row per sample, events and calibrations."""
    _execute_script(conn, SCHEMA_V1)


def migrate_1_to_2(conn: sqlite3.Connection) -> None:
    """v2: the sensor's own sample sequence number, to reconcile lost samples."""
    conn.execute("ALTER TABLE samples ADD COLUMN seq INTEGER")


def migrate_2_to_3(conn: sqlite3.Connection) -> None:
    """v3: the actuator that ran the run (unit, neutral, range), so analysis need not guess."""
    conn.execute("ALTER TABLE runs ADD COLUMN actuator_json TEXT")


def migrate_3_to_4(conn: sqlite3.Connection) -> None:
    """v4: when the run was last started or resumed, which `last` resolves by."""
    _execute_script(conn, "ALTER TABLE runs ADD COLUMN started_utc TEXT; "
                          "UPDATE runs SET started_utc = created_utc")


def migrate_4_to_5(conn: sqlite3.Connection) -> None:
    """v5: what each device's transport counters (frames, garbage, lost...) added during a
    point."""
    conn.execute("ALTER TABLE steps ADD COLUMN counters_json TEXT")


def migrate_5_to_6(conn: sqlite3.Connection) -> None:
    """v6: the analysis results a calibration found, which `report` and the API render."""
    conn.execute("ALTER TABLE calibrations ADD COLUMN state BLOB")


def migrate_6_to_7(conn: sqlite3.Connection) -> None:
    """v7: the supply voltage set for a point (NULL when the protocol sweeps none)."""
    conn.execute("ALTER TABLE steps ADD COLUMN voltage_v REAL")


def migrate_7_to_8(conn: sqlite3.Connection) -> None:
    """v8: every point's sample rows become column blocks; the rows table goes.

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
            conn.execute(INSERT_BLOCK, block_row(step_id, chunk, {
                c: data[:, i] for i, c in enumerate(cols)}))
            chunk += 1
    conn.execute("DROP TABLE samples")


# Schema v9's names of the steps columns that had others: one quantity, one name in SQLite,
# the API and the exports (a point's statistics over all its samples carry `_all_`).
RENAMED_STEP_COLUMNS = {
    "voltage_v": "voltage_set_v",
    **{f"{field}_{stat}": stat_column(field, stat)
       for field in STAT_FIELDS for stat in POINT_STATS},
}


def migrate_8_to_9(conn: sqlite3.Connection) -> None:
    """v9: the steps columns under the names the API and the exports use (thrust_n_mean ->
    thrust_all_mean_n, voltage_v -> voltage_set_v, ...); values are not touched."""
    for old, new in RENAMED_STEP_COLUMNS.items():
        conn.execute(f"ALTER TABLE steps RENAME COLUMN {old} TO {new}")


# MIGRATIONS[v] takes a store from version v to v + 1.
MIGRATIONS: tuple[Callable[[sqlite3.Connection], None], ...] = (
    migrate_0_to_1, migrate_1_to_2, migrate_2_to_3, migrate_3_to_4, migrate_4_to_5,
    migrate_5_to_6, migrate_6_to_7, migrate_7_to_8, migrate_8_to_9,
)
SCHEMA_VERSION = len(MIGRATIONS)


def version(conn: sqlite3.Connection) -> int:
    """The database's schema version (PRAGMA user_version)."""
    return conn.execute("PRAGMA user_version").fetchone()[0]


def create_schema(conn: sqlite3.Connection) -> None:
    """Apply every migration to an empty database (for tools and benchmarks)."""
    for migrate in MIGRATIONS:
        migrate(conn)
    conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")


def upgrade(conn: sqlite3.Connection, path: Path) -> None:
    """Bring the schema up to date, one migration per transaction.

    The version is re-read under the write lock, so two processes opening a new
    database at once never apply the same migration twice.
    """
    while (current := version(conn)) != SCHEMA_VERSION:
        if current > SCHEMA_VERSION:  # exit 2, as for a merge source of that version
            raise DataError(
                f"{path} has schema version {current}; this rigtool knows up to "
                f"{SCHEMA_VERSION}: upgrade rigtool"
            )
        with Transaction(conn, path):
            if version(conn) == current:
                MIGRATIONS[current](conn)
                conn.execute(f"PRAGMA user_version = {current + 1}")


def check_readable(conn: sqlite3.Connection, path: Path) -> None:
    """A read-only open cannot migrate: a version-8 store (the steps columns under their old
    names) is read through a view with the new names; an older one asks for one writing
    command."""
    current = version(conn)
    if current > SCHEMA_VERSION:
        raise DataError(f"{path} has schema version {current}; this rigtool knows up "
                         f"to {SCHEMA_VERSION}: upgrade rigtool")
    if current == 8 and SCHEMA_VERSION == 9:
        _renamed_steps_view(conn)
        return
    if current < SCHEMA_VERSION:
        raise StoreError(
            f"{path} has schema version {current} and needs a one-time upgrade to "
            f"{SCHEMA_VERSION}, which writes to it: run `rigtool calibrate` or `rigtool "
            "sweep` on it once, with free disk space and write access")


def _renamed_steps_view(conn: sqlite3.Connection) -> None:
    """A temporary view `steps` over a version-8 store's table with v9's column names: an
    unqualified name finds the temp schema first, so every reader sees the new names and the
    file is not written (a read-only archive opens)."""
    columns = [row[1] for row in conn.execute("PRAGMA main.table_info(steps)")]
    cells = ", ".join(f'"{c}" AS "{RENAMED_STEP_COLUMNS.get(c, c)}"' for c in columns)
    conn.execute(f"CREATE TEMP VIEW steps AS SELECT {cells} FROM main.steps")


_SCHEMA_OBJECTS = ("SELECT type, name, tbl_name FROM sqlite_master WHERE NOT (type = 'table' "
                   "AND name LIKE 'sqlite\\_%' ESCAPE '\\') LIMIT 1000")


@functools.cache
def _expected_schema() -> tuple[frozenset, dict[str, list]]:
    """The schema objects and table columns of a store this rigtool creates."""
    conn = sqlite3.connect(":memory:")
    try:
        create_schema(conn)
        objects = frozenset(conn.execute(_SCHEMA_OBJECTS).fetchall())
        return objects, {t: _table_info(conn, t) for t in TABLES}
    finally:
        conn.close()


def _table_info(conn: sqlite3.Connection, table: str) -> list:
    """A table's columns, and its kind (a WITHOUT ROWID or STRICT table is not rigtool's)."""
    kind = conn.execute("SELECT type, wr, strict FROM pragma_table_list WHERE schema = 'main' "
                        "AND name = ?", (table,)).fetchall()
    return [*kind, *conn.execute(f"PRAGMA main.table_info({table})").fetchall()]


def schema_difference(conn: sqlite3.Connection) -> str | None:
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
