"""The lab dataset (`rigtool export --all`) as the lab's other tools read it (issue 50 item 1):
DuckDB reads every table and runs every query docs/sql.md shows for the dataset; Spark itself
(pyspark with a JRE) runs the documented lines and reads both small tables by their path; a
dataset written with the earlier `_runs.pq` and `_calibrations.pq` is brought to the new names
by the next export, leaving no orphan and touching no partition."""

from __future__ import annotations

import importlib.util
import re
import shutil
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from rigtool.cli import main
from rigtool.store import Store

duckdb = pytest.importorskip("duckdb")

from .test_export_dataset import _sweep  # noqa: E402  (a calibratable run on the twin)

ROOT = Path(__file__).resolve().parents[1]
THRUSTERS = ("bow/1=a", "007", None)  # a `/` and `=` to encode, digits a reader would guess


def _dataset_section() -> str:
    text = (ROOT / "docs" / "sql.md").read_text()
    return text[text.index("## The lab dataset"):]


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """Three runs (one without a thruster id), two calibrated, exported with --all."""
    tmp = tmp_path_factory.mktemp("readers")
    db = tmp / "lab.sqlite"
    ids = [_sweep(tmp, db, 21 + i, t) for i, t in enumerate(THRUSTERS)]
    for run_id in ids[:2]:
        assert main(["calibrate", run_id, "--db", str(db), "--out", str(tmp / "cal")]) == 0
    out = tmp / "ds"
    assert main(["export", "--all", "--out", str(out), "--db", str(db)]) == 0
    with Store(db, read_only=True) as store:
        rows = {r: store.sample_count(r) for r in ids}
    return tmp, db, ids, out, rows


def test_duckdb_reads_every_table_and_runs_every_documented_query(lab):
    _, _, ids, out, rows = lab
    con = duckdb.connect()
    blocks = re.findall(r"```sql\n(.*?)```", _dataset_section(), re.S)
    statements = [s for b in blocks for s in b.replace("DIR", str(out)).split(";") if s.strip()]
    assert len(statements) >= 6
    results = [con.execute(s).fetchall() for s in statements]
    assert all(results[1:3]), "the samples queries found no rows"
    (c_p,) = [r for s, r in zip(statements, results, strict=True) if "c_p_fwd" in s]
    assert {row[0] for row in c_p} == {"bow/1=a", "007"}
    table = {"runs": f"{out}/_tables/runs.pq", "calibrations": f"{out}/_tables/calibrations.pq"}
    got = dict(con.execute(f"SELECT run_id, n_samples FROM read_parquet('{table['runs']}')")
               .fetchall())
    assert got == rows
    cal_runs = con.execute(f"SELECT DISTINCT run_id FROM read_parquet('{table['calibrations']}')"
                           ).fetchall()
    assert sorted(r for (r,) in cal_runs) == sorted(ids[:2])
    names = [d[0] for d in con.execute(f"SELECT * FROM read_parquet('{table['calibrations']}') "
                                       "LIMIT 0").description]
    assert "voltage_set_v" in names and "supply_voltage_v" not in names


def _spark():
    """A local Spark session, or a skip naming what is missing."""
    if shutil.which("java") is None:
        pytest.skip("no `java` on PATH: Spark needs a JRE (Debian: openjdk-17-jre-headless)")
    if importlib.util.find_spec("pyspark") is None:
        pytest.skip("pyspark is not installed (`pip install pyspark`, ~450 MB; not in the test "
                    "extra)")
    from pyspark.sql import SparkSession

    return (SparkSession.builder.master("local[1]").appName("rigtool-dataset-test")
            .config("spark.ui.enabled", "false").config("spark.sql.shuffle.partitions", "1")
            .getOrCreate())


@pytest.mark.slow
def test_spark_runs_the_documented_lines_and_reads_both_tables(lab):
    _, _, ids, out, rows = lab
    (code,) = [b for b in re.findall(r"```python\n(.*?)```", _dataset_section(), re.S)
               if "spark.read" in b]
    spark = _spark()
    try:
        scope = {"spark": spark}
        exec(compile(code.replace("DIR", str(out)), "docs/sql.md", "exec"), scope)
        counts = {(r["thruster_id"], r["run_id"]): r["count"] for r in
                  scope["samples"].groupBy("thruster_id", "run_id").count().collect()}
        assert counts == {(t, r): rows[r] for t, r in zip(THRUSTERS, ids, strict=True)}
        runs = {r["run_id"]: r["n_samples"] for r in scope["runs"].collect()}
        assert runs == rows
        cal = scope["calibrations"]
        assert {r["run_id"] for r in cal.select("run_id").distinct().collect()} == set(ids[:2])
        assert "voltage_set_v" in cal.columns
    finally:
        spark.stop()


def test_a_dataset_of_the_old_table_names_is_migrated_by_the_next_export(lab, tmp_path):
    """The tables as rigtool wrote them before (`_runs.pq`, `_calibrations.pq` beside the
    manifest, the voltage as `supply_voltage_v`): the next export writes `_tables/`, removes
    the old two and leaves every partition as it was."""
    _, db, _, out, _ = lab
    old = tmp_path / "old"
    shutil.copytree(out, old)
    cal = pq.read_table(old / "_tables" / "calibrations.pq")
    pq.write_table(cal.rename_columns(["supply_voltage_v" if n == "voltage_set_v" else n
                                       for n in cal.column_names]), old / "_calibrations.pq")
    (old / "_tables" / "runs.pq").rename(old / "_runs.pq")
    shutil.rmtree(old / "_tables")
    before = {p.relative_to(old).as_posix(): p.stat().st_mtime_ns
              for p in old.rglob("*.parquet")}
    assert main(["export", "--all", "--out", str(old), "--db", str(db)]) == 0
    files = {p.relative_to(old).as_posix() for p in old.rglob("*") if p.is_file()}
    assert files == {*before, "_rigtool_manifest.json", "_rigtool_export.lock",
                     "_tables/runs.pq", "_tables/calibrations.pq"}
    assert {p: (old / p).stat().st_mtime_ns for p in before} == before
    new = pq.read_table(old / "_tables" / "calibrations.pq")
    assert new.equals(pq.read_table(out / "_tables" / "calibrations.pq"))
    assert pq.read_table(old / "_tables" / "runs.pq").num_rows == 3
    assert main(["export", "--all", "--out", str(old), "--db", str(db)]) == 0  # nothing to do
    assert {p.relative_to(old).as_posix() for p in old.rglob("*") if p.is_file()} == files


def test_pyarrow_reads_the_folder_as_the_samples_table_alone(lab):
    """A pyarrow read of the whole folder skips `_tables/` and the manifest: one schema."""
    _, _, ids, out, rows = lab
    import pyarrow.dataset as ds

    ids_schema = ds.partitioning(pa.schema([("thruster_id", pa.string()),
                                            ("run_id", pa.string())]), flavor="hive")
    table = ds.dataset(out, format="parquet", partitioning=ids_schema).to_table(
        columns=["run_id", "thrust_n"])
    assert table.num_rows == sum(rows.values())


def test_export_all_takes_out_like_a_runs_export_and_the_old_form_still_works(lab, capsys):
    _, db, _, out, _ = lab
    capsys.readouterr()
    assert main(["export", "--all", str(out), "--db", str(db)]) == 0  # the older spelling
    captured = capsys.readouterr()
    assert "0 run(s) written, 3 unchanged" in captured.out
    assert f"`--all DIR` is deprecated; write `--all --out {out}`" in captured.err
    assert main(["export", "--all", str(out), "--out", str(out), "--db", str(db)]) == 2
    assert "give the dataset's folder once" in capsys.readouterr().err
