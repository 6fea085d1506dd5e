"""`rigtool export --all DIR`: the Hive-partitioned Parquet dataset, through the CLI. A second
export rewrites only the partitions of runs that changed (files counted by inode, mtime and
size); DuckDB and pyarrow read it to the store's row counts; hostile ids round-trip as
partition values; a failed or killed export leaves a readable dataset the next one repairs."""

from __future__ import annotations

import fcntl
import json
import os
import re
import signal
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.dataset as ds
import pytest

from rigtool.cli import main
from rigtool.ids import label_problem
from rigtool.store import Store

from .conftest import SMALL_PROTOCOL

duckdb = pytest.importorskip("duckdb")

NINE = SMALL_PROTOCOL.replace("values: [-50, 0, 50, 100]",
                              "values: [-100, -75, -50, -25, 0, 25, 50, 75, 100]")
AS_TEXT = "hive_types = {'thruster_id': VARCHAR, 'run_id': VARCHAR}"
ID_SCHEMA = ds.partitioning(pa.schema([("thruster_id", pa.string()), ("run_id", pa.string())]),
                            flavor="hive")


def _sweep(tmp: Path, db: Path, seed: int, thruster: str | None = None, text: str = NINE
           ) -> str:
    """Sweep a protocol on the twin into `db`; return the run id."""
    meta = "" if thruster is None else f"metadata: {{thruster_id: {json.dumps(thruster)}}}\n"
    path = tmp / f"p{seed}.yaml"
    path.write_text(text.replace("seed: 3", f"seed: {seed}").replace("command:\n",
                                                                    meta + "command:\n"))
    assert main(["sweep", str(path), "--sim", "--db", str(db)]) == 0
    with Store(db, read_only=True) as store:
        return store.resolve_run_id("last")


def _export(out: Path, db: Path) -> int:
    return main(["export", "--all", "--out", str(out), "--db", str(db)])


def _files(root: Path) -> dict[str, tuple[int, int, int]]:
    """Every file under `root`: relative path -> (inode, mtime_ns, size)."""
    return {p.relative_to(root).as_posix(): (p.stat().st_ino, p.stat().st_mtime_ns,
                                             p.stat().st_size)
            for p in root.rglob("*") if p.is_file()}


def _store_counts(db: Path) -> dict[str, tuple[int, float]]:
    """Per run: samples and the sum of thrust, as the store holds them."""
    with Store(db, read_only=True) as store:
        return {r: (len(t := store.samples(r, ["thrust_n"])["thrust_n"]),
                    round(float(np.nansum(t)), 6)) for r in store.run_ids()}


def _duckdb_counts(out: Path) -> dict[str, tuple[int, float]]:
    """Per run: rows and the sum of thrust of the documented DuckDB read of the dataset."""
    rows = duckdb.sql(f"SELECT run_id, count(*), sum(thrust_n) FROM read_parquet("
                      f"'{out}/**/*.parquet', hive_partitioning = true, {AS_TEXT}) "
                      "GROUP BY run_id").fetchall()
    return {r: (n, round(s or 0.0, 6)) for r, n, s in rows}


@pytest.fixture
def lab(tmp_path):
    """Two calibratable runs of two thrusters, exported once."""
    db = tmp_path / "lab.sqlite"
    ids = [_sweep(tmp_path, db, 11, "bow-1"), _sweep(tmp_path, db, 12, "stern-2")]
    assert main(["calibrate", ids[0], "--db", str(db), "--out", str(tmp_path / "cal")]) == 0
    out = tmp_path / "ds"
    assert _export(out, db) == 0
    return tmp_path, db, ids, out


def test_a_second_export_rewrites_only_the_new_and_the_recalibrated_run(lab, capsys):
    tmp, db, ids, out = lab
    before = _files(out)
    new = _sweep(tmp, db, 13, "bow-1")
    assert main(["calibrate", ids[1], "--db", str(db), "--out", str(tmp / "cal")]) == 0
    capsys.readouterr()
    assert _export(out, db) == 0
    assert "2 run(s) written, 1 unchanged" in capsys.readouterr().out
    after = _files(out)
    touched = {p for p in after if before.get(p) != after[p]}
    partitions = {p for p in touched if "=" in p}
    assert partitions == {f"thruster_id=stern-2/run_id={ids[1]}/samples.parquet",
                          f"thruster_id=bow-1/run_id={new}/samples.parquet"}
    assert touched - partitions == {"_rigtool_manifest.json", "_tables/calibrations.pq", "_tables/runs.pq"}
    assert set(before) - set(after) == set()
    # nothing changed since: an export touches no file at all, not even the manifest
    assert _export(out, db) == 0
    assert _files(out) == after
    assert "0 run(s) written, 3 unchanged" in capsys.readouterr().out


def test_a_first_export_killed_while_marking_its_folder_is_taken_up_again(lab, capsys):
    """A kill -9 of the first export into a new folder leaves its lock and the manifest's
    half-written temporary file: the next export takes the folder, not refuses it."""
    tmp, db, ids, _ = lab
    out = tmp / "fresh"
    out.mkdir()
    (out / "_rigtool_export.lock").write_text("")
    (out / "._rigtool_manifest.json.tmp").write_text('{"runs": {"x"')
    assert _export(out, db) == 0
    assert _duckdb_counts(out) == _store_counts(db)
    assert not (out / "._rigtool_manifest.json.tmp").exists()
    # anything else (or the temporary name as a symlink) is still not rigtool's to take
    other = tmp / "other"
    other.mkdir()
    (other / "._rigtool_manifest.json.tmp").symlink_to(tmp / "lab.sqlite")
    capsys.readouterr()
    assert _export(other, db) == 2
    assert "holds files but no rigtool dataset" in capsys.readouterr().err


def test_duckdb_and_pyarrow_read_the_store_s_row_counts(lab):
    tmp, db, ids, out = lab
    expected = _store_counts(db)
    assert _duckdb_counts(out) == expected
    ((total,),) = duckdb.sql(f"SELECT count(*) FROM read_parquet('{out}/**/*.parquet', "
                             "hive_partitioning = true)").fetchall()  # the query
    assert total == sum(n for n, _ in expected.values())
    table = ds.dataset(out, format="parquet", partitioning=ID_SCHEMA).to_table()
    frame = table.to_pandas()
    assert {r: (len(g), round(g.thrust_n.sum(), 6)) for r, g in frame.groupby("run_id")} \
        == expected
    assert dict(zip(frame.run_id, frame.thruster_id, strict=True)) == {ids[0]: "bow-1",
                                                                       ids[1]: "stern-2"}
    with Store(db, read_only=True) as store:  # a sample row carries its point's columns
        points = store.points(ids[0])
    mine = frame[frame.run_id == ids[0]].groupby("step_idx")
    assert (mine.point_command.first().to_numpy() == points["command"]).all()
    assert (mine.size().to_numpy() == points["n_samples"]).all()
    assert set(frame.point_status) == {"ok"} and set(frame.run_status) == {"completed"}
    manifest = json.loads((out / "_rigtool_manifest.json").read_text())
    assert {r: e["rows"] for r, e in manifest["runs"].items()} == {
        r: n for r, (n, _) in expected.items()}
    assert manifest["runs"][ids[0]]["calibrated_utc"] is not None
    assert manifest["runs"][ids[1]]["calibrated_utc"] is None
    cal = duckdb.sql(f"SELECT DISTINCT run_id, thruster_id FROM "
                     f"read_parquet('{out}/_tables/calibrations.pq')").fetchall()
    assert cal == [(ids[0], "bow-1")]
    runs = duckdb.sql(f"SELECT run_id, thruster_id, name, n_points, n_samples, calibrated_utc "
                      f"IS NOT NULL FROM read_parquet('{out}/_tables/runs.pq') ORDER BY run_id").fetchall()
    assert runs == [(ids[0], "bow-1", "small", 9, expected[ids[0]][0], True),
                    (ids[1], "stern-2", "small", 9, expected[ids[1]][0], False)]


HOSTILE = ["a/b", "x=y", "50%", "%2F", "..", ".", "007", "1e3", "tab\there", "line\nbreak",
           "bell\x07", "sp ace", "ü-ß", "q'\"#?*:\\{[]^<>|", "-rf", "~", "__HIVE_DEFAULT_PARTITION__"]


def test_hostile_ids_round_trip_as_partition_values(tmp_path):
    db = tmp_path / "h.sqlite"
    ids = {}
    for i, thruster in enumerate([*HOSTILE, None, ""]):
        hidden = thruster is not None and label_problem(thruster) is not None
        run_id = _sweep(tmp_path, db, 20 + i, "placeholder" if hidden else thruster,
                        SMALL_PROTOCOL)
        if hidden:  # a protocol refuses it; a database from elsewhere may hold it
            with sqlite3.connect(db) as con:
                con.execute("UPDATE runs SET metadata_json = json_set(metadata_json, "
                            "'$.thruster_id', ?) WHERE id = ?", (thruster, run_id))
            con.close()
        ids[run_id] = thruster
    # a crafted database: a run id with a path in it, in every table that names it
    bad_run = "../../escape/run_id=x%2F"
    victim = next(iter(ids))
    con = sqlite3.connect(db)
    con.execute("PRAGMA foreign_keys = OFF")
    for table, column in (("runs", "id"), ("steps", "run_id"), ("events", "run_id")):
        con.execute(f"UPDATE {table} SET {column} = ? WHERE {column} = ?", (bad_run, victim))
    con.commit()
    con.close()
    ids[bad_run] = ids.pop(victim)
    out = tmp_path / "deep" / "ds"
    assert _export(out, db) == 0
    assert not (tmp_path / "escape").exists() and not (tmp_path / "deep" / "escape").exists()
    assert all(p.resolve().is_relative_to(out.resolve()) for p in out.rglob("*"))
    want = {r: (t or None) for r, t in ids.items()}  # "" is Hive's null, as Spark writes it
    got = duckdb.sql(f"SELECT DISTINCT run_id, thruster_id FROM read_parquet("
                     f"'{out}/**/*.parquet', hive_partitioning = true, {AS_TEXT})").fetchall()
    assert dict(got) == want
    table = ds.dataset(out, format="parquet", partitioning=ID_SCHEMA).to_table(
        columns=["run_id", "thruster_id"]).to_pandas().drop_duplicates()
    # pyarrow (and Spark) read Hive's null marker back as null, even percent-encoded
    want_arrow = {r: None if t == "__HIVE_DEFAULT_PARTITION__" else t for r, t in want.items()}
    assert {r: (None if t is None or t != t else t)
            for r, t in zip(table.run_id, table.thruster_id, strict=True)} == want_arrow
    counts = _store_counts(db)
    assert _duckdb_counts(out) == counts


def test_an_id_too_long_for_a_folder_is_refused_by_the_protocol(tmp_path, capsys):
    """Issue 49: a 300-byte thruster id was swept, then blocked every `export --all`. The
    protocol now refuses what the dataset cannot file, by the dataset's own rule."""
    db = tmp_path / "long.sqlite"
    path = tmp_path / "long.yaml"
    path.write_text(NINE.replace("command:\n", 'metadata: {thruster_id: "' + "x" * 300
                                 + '"}\ncommand:\n'))
    assert main(["sweep", str(path), "--sim", "--db", str(db)]) == 2
    err = capsys.readouterr().err
    assert re.search(rf"{re.escape(str(path))}:\d+: metadata\.thruster_id: .*300 bytes", err), err
    assert "Traceback" not in err and not db.exists()


@pytest.mark.parametrize("bad", ["x" * 300, "\ud800"], ids=["too-long", "lone-surrogate"])
def test_export_leaves_out_a_stored_run_whose_id_no_folder_takes(tmp_path, capsys, bad):
    """An older database holding such an id (written directly in the store): the export
    writes every other run and names the one it leaves out."""
    db = tmp_path / "old.sqlite"
    good = _sweep(tmp_path, db, 5, "bow-1", SMALL_PROTOCOL)
    victim = _sweep(tmp_path, db, 6, "stern-1", SMALL_PROTOCOL)
    con = sqlite3.connect(db)
    con.execute("UPDATE runs SET metadata_json = ? WHERE id = ?",
                (json.dumps({"thruster_id": bad}), victim))
    con.commit()
    con.close()
    capsys.readouterr()
    out = tmp_path / "ds"
    assert _export(out, db) == 0
    captured = capsys.readouterr()
    assert f"warning: run {victim!r}: its thruster_id" in captured.err, captured.err
    assert "left out of the dataset" in captured.err and "Traceback" not in captured.err
    assert "1 left out" in captured.out
    assert set(_duckdb_counts(out)) == {good}
    assert _export(out, db) == 0  # and again: the dataset is not blocked


def _export_process(out: Path, db: Path, fsize: int, crash: bool) -> subprocess.CompletedProcess:
    """`rigtool export --all` in a process whose files may grow to `fsize` bytes only: past
    that, a write fails (EFBIG), or, with `crash`, the kernel kills the process mid-write."""
    code = ("import signal, sys; from rigtool.cli import main; "
            + ("signal.signal(signal.SIGXFSZ, signal.SIG_DFL); " if crash else "")
            + "sys.exit(main(sys.argv[1:]))")

    def limit() -> None:
        import resource

        resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))

    return subprocess.run([sys.executable, "-c", code, "export", "--all", "--out", str(out), "--db",
                           str(db)], capture_output=True, text=True, preexec_fn=limit,
                          timeout=120)


@pytest.mark.parametrize("crash", [False, True], ids=["write-fails", "killed"])
def test_an_interrupted_export_leaves_a_consistent_dataset(lab, crash):
    tmp, db, ids, out = lab
    before = _store_counts(db)
    old_manifest = (out / "_rigtool_manifest.json").read_bytes()
    big = NINE.replace("samples: 200, rate_hz: 500", "samples: 4000, rate_hz: 2000")
    new = _sweep(tmp, db, 14, "bow-1", big)
    proc = _export_process(out, db, 60_000, crash)
    if crash:
        assert proc.returncode == -signal.SIGXFSZ, proc.stderr
        assert list(out.rglob(".samples.parquet.tmp"))  # the half-written file, left behind
    else:
        assert proc.returncode == 1 and "File too large" in proc.stderr, proc.stderr
        assert "Traceback" not in proc.stderr
        assert not list(out.rglob("*.tmp"))
    # every reader still sees the old dataset, whole; the manifest is the old one
    assert (out / "_rigtool_manifest.json").read_bytes() == old_manifest
    assert _duckdb_counts(out) == {r: before[r] for r in ids}
    assert len(ds.dataset(out, format="parquet", partitioning=ID_SCHEMA).to_table()) == sum(
        n for n, _ in before.values())
    # the next export repairs it
    assert _export(out, db) == 0
    assert _duckdb_counts(out) == _store_counts(db) and new in _duckdb_counts(out)
    assert not list(out.rglob("*.tmp"))


def test_runs_of_another_database_are_kept_and_marked(lab, capsys):
    tmp, db, ids, out = lab
    other = tmp / "rig-b.sqlite"
    theirs = _sweep(tmp, other, 30, "bow-1", SMALL_PROTOCOL)
    capsys.readouterr()
    assert _export(out, other) == 0
    assert "1 run(s) written, 0 unchanged, 2 kept (not in this database)" in \
        capsys.readouterr().out
    assert _duckdb_counts(out) == {**_store_counts(db), **_store_counts(other)}
    runs = json.loads((out / "_rigtool_manifest.json").read_text())["runs"]
    assert {r: e["in_last_source"] for r, e in runs.items()} == {
        ids[0]: False, ids[1]: False, theirs: True}
    assert runs[theirs]["source"] == str(other.resolve())


def test_usage_errors_exit_2_naming_the_folder(lab, capsys):
    tmp, db, _, out = lab
    a_file = tmp / "file.txt"
    a_file.write_text("x")
    foreign = tmp / "mine"
    foreign.mkdir()
    (foreign / "thesis.tex").write_text("x")
    for target, words in ((a_file, "is a file"), (a_file / "sub", "a part of the path is a file"),
                          (foreign, "holds files but no rigtool dataset")):
        assert _export(target, db) == 2
        err = capsys.readouterr().err
        assert str(target) in err and words in err and "Traceback" not in err
    assert a_file.read_text() == "x" and sorted(os.listdir(foreign)) == ["thesis.tex"]
    assert main(["export", "--all", str(out), "--format", "csv", "--db", str(db)]) == 2
    assert main(["export", "last", "--all", str(out), "--db", str(db)]) == 2
    manifest = out / "_rigtool_manifest.json"
    newer = json.loads(manifest.read_text())
    newer["dataset_version"] = 99
    huge = json.loads(manifest.read_text())
    next(iter(huge["runs"].values()))["rows"] = 10**30
    for damaged in ("{not json", "[" * 100_000, '{"format": "rigtool-parquet-dataset", "runs": '
                    '{"r": {"rows": -1}}}', json.dumps(newer), json.dumps(huge)):
        manifest.write_text(damaged)
        assert _export(out, db) == 2
        err = capsys.readouterr().err
        assert "dataset manifest" in err and str(manifest) in err and "Traceback" not in err


def test_a_second_exporter_is_refused_while_one_writes(lab, capsys):
    _, db, _, out = lab
    with (out / "_rigtool_export.lock").open("a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        assert _export(out, db) == 1
    assert "another rigtool export is writing" in capsys.readouterr().err
    assert _export(out, db) == 0


def test_the_documented_duckdb_and_pyarrow_reads_work(lab):
    """docs/sql.md's DuckDB view and queries and its pyarrow snippet, run on a dataset."""
    _, db, ids, out = lab
    text = (Path(__file__).resolve().parents[1] / "docs" / "sql.md").read_text()
    section = text[text.index("## The lab dataset"):]
    (sql,) = [b for b in re.findall(r"```sql\n(.*?)```", section, re.S) if "CREATE VIEW" in b]
    con = duckdb.connect()
    view, curve, noise = [s for s in sql.replace("DIR", str(out)).split(";") if s.strip()]
    con.execute(view)
    rows = con.execute(curve).fetchall()
    assert {(t, r) for t, r, _, _ in rows} == {("bow-1", ids[0]), ("stern-2", ids[1])}
    assert len(rows) == 2 * 9
    per_point = con.execute(noise).fetchall()
    assert sum(n for *_, n, _ in per_point) == sum(n for n, _ in _store_counts(db).values())
    (code,) = [b for b in re.findall(r"```python\n(.*?)```", section, re.S) if "ds.dataset" in b]
    scope: dict = {}
    exec(compile(code.replace('"DIR"', repr(str(out))), "docs/sql.md", "exec"), scope)
    bow = scope["bow"].to_pandas()
    assert set(bow.run_id) == {ids[0]} and len(bow) == _store_counts(db)[ids[0]][0]


def test_a_run_that_changed_thruster_moves_and_an_empty_run_is_an_empty_partition(lab, capsys):
    """A copy of a run in another database with another thruster id (crafted or edited):
    the run's partition moves, the old folder goes. A run with no points: a file of no rows
    in the same schema."""
    tmp, db, ids, out = lab
    con = sqlite3.connect(db)
    con.execute("UPDATE runs SET metadata_json = json_set(metadata_json, '$.thruster_id', "
                "'port-3') WHERE id = ?", (ids[1],))
    con.execute("PRAGMA foreign_keys = ON")
    con.execute("DELETE FROM steps WHERE run_id = ?", (ids[0],))  # its blocks cascade
    con.commit()
    con.close()
    assert _export(out, db) == 0
    assert not (out / "thruster_id=stern-2").exists()
    assert (out / "thruster_id=port-3" / f"run_id={ids[1]}" / "samples.parquet").is_file()
    assert _duckdb_counts(out) == {ids[1]: _store_counts(db)[ids[1]]}
    empty = ds.dataset(out / "thruster_id=bow-1", format="parquet", partitioning="hive")
    assert empty.count_rows() == 0 and "thrust_n" in empty.schema.names
    assert json.loads((out / "_rigtool_manifest.json").read_text())["runs"][ids[0]]["rows"] == 0


def test_a_planted_symlink_is_refused_and_nothing_is_written_outside(lab, capsys):
    tmp, db, _, out = lab
    elsewhere = tmp / "elsewhere"
    elsewhere.mkdir()
    (out / "thruster_id=new-1").symlink_to(elsewhere, target_is_directory=True)
    new = _sweep(tmp, db, 40, "new-1", SMALL_PROTOCOL)
    capsys.readouterr()
    assert _export(out, db) == 2
    assert "is a symlink" in capsys.readouterr().err
    assert list(elsewhere.iterdir()) == []
    victim = tmp / "victim.txt"
    victim.write_text("precious")
    (out / "thruster_id=new-1").unlink()
    part = out / "thruster_id=new-1" / f"run_id={new}"
    part.mkdir(parents=True)
    (part / ".samples.parquet.tmp").symlink_to(victim)  # a temporary name, planted
    assert _export(out, db) == 0
    assert (part / "samples.parquet").is_file() and not (part / ".samples.parquet.tmp").exists()
    assert victim.read_text() == "precious"
    assert _duckdb_counts(out) == _store_counts(db)


@pytest.mark.parametrize("plant", ["fifo", "symlink"])
def test_a_planted_lock_file_is_refused_without_hanging(lab, capsys, plant):
    tmp, db, _, out = lab
    lock = out / "_rigtool_export.lock"
    lock.unlink()
    victim = tmp / "victim.txt"
    victim.write_text("precious")
    if plant == "fifo":
        os.mkfifo(lock)  # opening it to write would wait for a reader for ever
    else:
        lock.symlink_to(victim)
    assert _export(out, db) == 2
    err = capsys.readouterr().err
    assert "export lock" in err or "is not a file" in err
    assert victim.read_text() == "precious"


def test_the_manifest_checkpoints_what_a_failed_export_already_wrote(lab, capsys, monkeypatch):
    """With a checkpoint after every run, an export that fails on its second new run (a folder
    where its file must go) has the first in the manifest: the next export writes only the
    second."""
    from rigtool.dataset import update

    tmp, db, ids, out = lab
    first, second = _sweep(tmp, db, 50, "bow-1"), _sweep(tmp, db, 51, "bow-1")
    blocker = out / "thruster_id=bow-1" / f"run_id={second}" / "samples.parquet"
    (blocker / "x").mkdir(parents=True)
    monkeypatch.setattr(update, "CHECKPOINT_S", 0.0)
    assert _export(out, db) == 1
    assert "rigtool: error:" in capsys.readouterr().err
    runs = json.loads((out / "_rigtool_manifest.json").read_text())["runs"]
    assert first in runs and second not in runs
    (blocker / "x").rmdir()
    blocker.rmdir()
    assert _export(out, db) == 0
    assert "1 run(s) written, 3 unchanged" in capsys.readouterr().out
    assert _duckdb_counts(out) == _store_counts(db)
