"""Export of runs to CSV and Parquet: every point, sample and event, readable without rigtool."""

from __future__ import annotations

import csv

import pyarrow.parquet as pq
import pytest

from rigtool.cli import main
from rigtool.store import Store

from .conftest import SMALL_PROTOCOL


@pytest.fixture
def run_db(write_yaml, db_path):
    assert main(["sweep", str(write_yaml(SMALL_PROTOCOL)), "--sim", "--db", str(db_path)]) == 0
    return db_path


def test_csv_export_roundtrips(run_db, tmp_path, capsys):
    out = tmp_path / "exp"
    assert main(["export", "last", "--out", str(out), "--db", str(run_db)]) == 0
    files = capsys.readouterr().out.split()
    assert len(files) == 3
    store = Store(run_db)
    run_id = store.resolve_run_id("last")
    with open(out / f"{run_id}-samples.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 4 * 200
    assert {r["step_idx"] for r in rows} == {"0", "1", "2", "3"}
    db_thrust = store.samples(run_id, ["thrust_n"])["thrust_n"]
    assert [float(r["thrust_n"]) for r in rows[:5]] == pytest.approx(list(db_thrust[:5]))
    with open(out / f"{run_id}-points.csv") as fh:
        points = list(csv.DictReader(fh))
    assert [float(p["command"]) for p in points] == [-50, 0, 50, 100]
    with open(out / f"{run_id}-events.csv") as fh:
        assert "tare" in {e["kind"] for e in csv.DictReader(fh)}


def test_parquet_export_has_typed_columns(run_db, tmp_path):
    out = tmp_path / "pq"
    assert main(["export", "last", "--format", "parquet", "--out", str(out), "--db", str(run_db)]) == 0
    run_id = Store(run_db).resolve_run_id("last")
    samples = pq.read_table(out / f"{run_id}-samples.parquet")
    assert samples.num_rows == 800
    assert str(samples.schema.field("thrust_n").type) == "double"
    assert str(samples.schema.field("step_idx").type) == "int64"
    points = pq.read_table(out / f"{run_id}-points.parquet").to_pydict()
    assert points["direction"] == ["up"] * 4


def test_export_unknown_run_is_usage_error(run_db, tmp_path, capsys):
    assert main(["export", "nope", "--out", str(tmp_path), "--db", str(run_db)]) == 2
    assert "no run 'nope'" in capsys.readouterr().err
