"""One quantity, one name (issue 50 item 3): a point's statistics over all of its samples are
`thrust_all_mean_n` ... and the supply voltage set is `voltage_set_v` in the SQLite store, the
Python API, the CSV and Parquet exports; a database of schema version 8 (built here with the old
column names) opens with the new ones and its values unchanged; every SQLite query of
docs/sql.md runs in sqlite3 on a real run's database and finds rows."""

from __future__ import annotations

import csv
import re
import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

import rigtool
from rigtool.cli import main
from rigtool.store import SCHEMA_VERSION, Store

from .conftest import SMALL_PROTOCOL

ROOT = Path(__file__).resolve().parents[1]
VOLTAGE_SWEEP = SMALL_PROTOCOL.replace(
    "simulator: {profile: can-bldc, seed: 3}",
    "simulator: {profile: can-bldc, seed: 5, overrides: {feedback: [speed_rpm, current_a, "
    "voltage_v]}}").replace("timing:", "voltage: {unit: V, values: [12, 16]}\ntiming:")
STATS = [f"{ch}_all_{s}_{u}" for ch, u in (("thrust", "n"), ("speed", "rpm"), ("current", "a"))
         for s in ("mean", "std", "min", "max")]
OLD_STATS = [f"{ch}_{s}" for ch in ("thrust_n", "speed_rpm", "current_a")
             for s in ("mean", "std", "min", "max")]


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    """A voltage sweep on the twin, calibrated: its database and run id."""
    tmp = tmp_path_factory.mktemp("names")
    path = tmp / "volts.yaml"
    path.write_text(VOLTAGE_SWEEP)
    db = tmp / "lab.sqlite"
    assert main(["sweep", str(path), "--sim", "--db", str(db)]) == 0
    assert main(["calibrate", "last", "--db", str(db), "--out", str(tmp / "cal")]) == 0
    with Store(db, read_only=True) as store:
        return tmp, db, store.resolve_run_id("last")


def _columns(db: Path, table: str) -> list[str]:
    con = sqlite3.connect(db)
    try:
        return [r[1] for r in con.execute(f"PRAGMA table_info({table})")]
    finally:
        con.close()


def test_the_same_names_in_sqlite_the_api_csv_and_parquet(swept):
    tmp, db, run_id = swept
    assert {*STATS, "voltage_set_v"} <= set(_columns(db, "steps"))
    assert not {*OLD_STATS, "voltage_v"} & set(_columns(db, "steps"))
    with rigtool.open(db) as lab:
        points = lab.run(run_id).points()
    assert {*STATS, "voltage_set_v"} <= set(points)
    assert set(points["voltage_set_v"].tolist()) == {12.0, 16.0}
    for fmt in ("csv", "parquet"):
        assert main(["export", run_id, "--format", fmt, "--out", str(tmp / fmt),
                     "--db", str(db)]) == 0
    with (tmp / "csv" / f"{run_id}-points.csv").open(newline="") as fh:
        header = next(csv.reader(fh))
    names = pq.read_schema(tmp / "parquet" / f"{run_id}-points.parquet").names
    for got in (header, names):
        assert {*STATS, "voltage_set_v"} <= set(got) and "thrust_mean_n" not in got
    samples = pq.read_schema(tmp / "parquet" / f"{run_id}-samples.parquet").names
    assert "voltage_v" in samples and "voltage_set_v" not in samples  # measured, not set


def test_a_schema_8_database_opens_with_the_new_names(swept, tmp_path):
    """The test builds a version-8 store from a real run: the steps columns renamed back to
    the names version 8 had. Opening it migrates in place; every value stays."""
    _, db, run_id = swept
    old = tmp_path / "old.sqlite"
    src, dst = sqlite3.connect(db), sqlite3.connect(old)
    src.backup(dst)
    src.close()
    for new, name in [*zip(STATS, OLD_STATS, strict=True), ("voltage_set_v", "voltage_v")]:
        dst.execute(f"ALTER TABLE steps RENAME COLUMN {new} TO {name}")
    dst.execute("PRAGMA user_version = 8")
    dst.commit()
    stored = dst.execute("SELECT idx, thrust_n_mean, current_a_max, voltage_v FROM steps "
                         "ORDER BY idx").fetchall()
    dst.close()
    archive = tmp_path / "archive.sqlite"  # a read-only copy: read under the new names as it is
    shutil.copy(old, archive)
    archive.chmod(0o444)
    with Store(archive, read_only=True) as store:
        kept = store.points(run_id)
    assert sqlite3.connect(archive).execute("PRAGMA user_version").fetchone()[0] == 8
    assert main(["show", run_id, "--db", str(archive)]) == 0
    with Store(old) as store:
        assert store.version == SCHEMA_VERSION == 9
        p = store.points(run_id)
    assert {*STATS, "voltage_set_v"} <= set(_columns(old, "steps"))
    assert not {*OLD_STATS, "voltage_v"} & set(_columns(old, "steps"))
    got = list(zip(p["step_idx"].tolist(), p["thrust_all_mean_n"].tolist(),
                   p["current_all_max_a"].tolist(), p["voltage_set_v"].tolist(), strict=True))
    assert got == stored
    assert all(np.array_equal(kept[k], p[k], equal_nan=True) for k in (*STATS, "voltage_set_v"))
    with Store(db, read_only=True) as store:
        assert all(np.array_equal(store.points(run_id)[k], p[k], equal_nan=True)
                   for k in (*STATS, "voltage_set_v"))


def _sqlite_statements() -> list[str]:
    """Every statement of docs/sql.md's SQLite section (before the dataset's)."""
    text = (ROOT / "docs" / "sql.md").read_text()
    section = text[:text.index("## Several rigs")]
    return [s.strip() for block in re.findall(r"```sql\n(.*?)```", section, re.S)
            for s in block.split(";") if s.strip()]


def test_every_sqlite_query_of_the_docs_runs_on_a_real_run(swept):
    _, db, run_id = swept
    statements = _sqlite_statements()
    assert len(statements) == 11
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    con.row_factory = sqlite3.Row
    results = {}
    for sql in statements:
        rows = con.execute(sql.replace("'RUN_A', 'RUN_B'", ":run"), {"run": run_id}).fetchall()
        results[sql] = rows
        if "import" in sql:  # the imported runs: this database holds none
            assert rows == []
        elif "up_minus_down_n" not in sql:  # a sweep in one direction has no hysteresis
            assert rows, sql
    (events,) = [rows for sql, rows in results.items() if "FROM events" in sql]
    assert {r["kind"] for r in events} >= {"run_start", "tare", "voltage"}
    assert all(r["detail"] for r in events)  # each event shows its message or its detail
    (curve,) = [rows for sql, rows in results.items() if "worst_std_n" in sql]
    assert len(curve) == 4 and all(r["thrust_n"] is not None for r in curve)
    con.close()
