"""Everything rigtool reads back is hostile until checked: crafted database fields, merge
sources and calibration folders end in a rigtool error (through the CLI: exit 2, one line, no
traceback, within 10 CPU s under 1 GiB of address space), never write to a merge source, and
leave the database they were aimed at unchanged. Handcrafted cases run through the CLI;
hypothesis (derandomized) fuzzes the same readers in-process through the API."""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import re
import resource
import shutil
import sqlite3
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import pytest
from hypothesis import HealthCheck, event, given, reject, settings
from hypothesis import strategies as st

import rigtool
from rigtool.artefacts import state
from rigtool.cli import main
from rigtool.errors import DataError, RigtoolError, UsageError
from rigtool.export import export_run
from rigtool.readback import (
    CALIBRATION_COLUMNS,
    CALIBRATION_FORMAT,
    EVENT_COLUMNS,
    MAX_JSON_BYTES,
    MAX_JSON_DEPTH,
    RUN_COLUMNS,
    STEP_COLUMNS,
)
from rigtool.store import SAMPLE_COLUMNS, Store

from .conftest import PROTOCOLS
from .hostile import run_cli

CLI_SECONDS = 10.0  # CPU seconds a refused CLI run may take
DEMO = (PROTOCOLS / "quick-demo.yaml").read_text().replace("samples: 1000", "samples: 200")
FUZZ = settings(max_examples=40, derandomize=True, deadline=None, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture,
                                       HealthCheck.filter_too_much, HealthCheck.too_slow])


@dataclass(frozen=True)
class Base:
    """One calibrated simulator run, built once for the module."""

    root: Path
    db: Path
    other: Path  # a store with another run: a sound merge source
    empty: Path  # a store with no runs: the merge target
    run_id: str
    folder: Path  # calibrations/<run-id>/


@pytest.fixture(scope="module")
def base(tmp_path_factory: pytest.TempPathFactory) -> Base:
    """A calibrated quick-demo run (200 samples a point), another run, and an empty store."""
    root = tmp_path_factory.mktemp("readback")
    protocol = root / "demo.yaml"
    protocol.write_text(DEMO)
    db = root / "base.sqlite"
    assert main(["sweep", str(protocol), "--sim", "--db", str(db)]) == 0
    assert main(["calibrate", "last", "--db", str(db), "--out", str(root / "cal")]) == 0
    other = root / "other.sqlite"
    assert main(["sweep", str(protocol), "--sim", "--db", str(other)]) == 0
    with Store(db, read_only=True) as store:
        run_id = store.resolve_run_id("last")
    empty = root / "empty.sqlite"
    Store(empty).close()
    return Base(root, db, other, empty, run_id, root / "cal" / run_id)


def _digest(path: Path) -> str:
    """The SHA-256 of a file's bytes."""
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _crafted(source: Path, target: Path, *statements: tuple[str, tuple]) -> Path:
    """A copy of `source` changed by raw SQL (foreign keys off), closed cleanly (no -wal)."""
    shutil.copyfile(source, target)
    conn = sqlite3.connect(target)
    try:
        conn.execute("PRAGMA foreign_keys=OFF")
        with conn:
            for sql, args in statements:
                conn.execute(sql, args)
    finally:
        conn.close()
    return target


def _sql(sql: str, *args: object) -> tuple[str, tuple]:
    """One statement for `_crafted`."""
    return sql, args


def _state_of_run(db: Path, run_id: str) -> bytes:
    """The base run's stored calibration state, re-encoded as if it belonged to `run_id`."""
    with Store(db, read_only=True) as store:
        data = state.decode(store.latest_calibration(store.resolve_run_id("last"))["state"])
    data["calibration"] = dataclasses.replace(data["calibration"], run_id=run_id)
    return state.encode(data)


def _refused(proc: subprocess.CompletedProcess, seconds: float) -> str:
    """The one error line of a CLI run that must end in exit 2."""
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-3000:])
    *before, last = proc.stderr.strip().splitlines()
    assert last.startswith("rigtool: error: "), last
    assert all(line.startswith("warning: ") for line in before), before  # the run's own
    assert seconds < CLI_SECONDS
    return last


def _children_cpu_s() -> float:
    """User + system CPU seconds of this process's finished child processes."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _cli(tmp_path: Path, *args: str | Path) -> tuple[str, float]:
    """The error line and the CPU seconds of a CLI run that must be refused. CPU, not wall
    time: the bound is on the work a crafted file makes (a loaded machine stretches the wall
    time, not the work); `run_cli` stops a run that hangs after TIME_LIMIT_S of wall time."""
    cpu0 = _children_cpu_s()
    proc = run_cli(*args, cwd=tmp_path)
    seconds = _children_cpu_s() - cpu0
    return _refused(proc, seconds), seconds


def _command(name: str, db: Path, ref: str, out: Path) -> list[str | Path]:
    """The arguments of one reading command on `db`."""
    if name == "export-all":
        return ["export", "--all", "--out", out, "--db", db]
    extra = [] if name == "show" else ["--out", out]
    extra += ["--format", "c-header"] if name == "export-cal" else []
    return [name, ref, "--db", db, *extra]


# -- database fields, through the CLI -----------------------------------------------------
FIRST_BLOCK = "(SELECT min(id) FROM sample_blocks)"
QUICK_WRITE = [_sql("PRAGMA journal_mode = DELETE"), _sql("PRAGMA synchronous = OFF")]  # 400 MB once
NO_SAMPLES = ", ".join(f"{c} = NULL" for c in SAMPLE_COLUMNS[1:])
FIELDS = {
    "n=10^12 in a point": ([_sql("UPDATE steps SET n = 1000000000000 WHERE idx = 0")],
                          ("show", "calibrate"), "point 0, steps.n"),
    "negative n in a point": ([_sql("UPDATE steps SET n = -1 WHERE idx = 1")], ("report",),
                              "steps.n"),
    "n=10^12 in a block": ([_sql(f"UPDATE sample_blocks SET n = 1000000000000 WHERE id = "
                                 f"{FIRST_BLOCK}")], ("export", "calibrate"), "sample_blocks.n"),
    "negative n in a block": ([_sql(f"UPDATE sample_blocks SET n = -5 WHERE id = {FIRST_BLOCK}")],
                              ("report",), "sample_blocks.n"),
    "samples claimed without data": ([_sql(f"UPDATE sample_blocks SET n = 65536, {NO_SAMPLES}")],
                                     ("export",), "sample_blocks.t_s"),
    "a blob of the wrong length": ([_sql("UPDATE sample_blocks SET thrust_n = X'0001'")],
                                   ("calibrate",), "sample_blocks.thrust_n"),
    "text in a blob column": ([_sql("UPDATE sample_blocks SET t_s = 'abc'")], ("export",),
                              "sample_blocks.t_s"),
    "an infinite sample": ([_sql(f"UPDATE sample_blocks SET thrust_n = CAST(X'000000000000F07F' "
                                 f"|| substr(thrust_n, 9) AS BLOB) WHERE id = {FIRST_BLOCK}")],
                           ("export", "calibrate"), "column thrust_n holds a sample of inf"),
    "a 1e308 sample": ([_sql(f"UPDATE sample_blocks SET current_a = CAST(X'FFFFFFFFFFFFDF7F' "
                             f"|| substr(current_a, 9) AS BLOB) WHERE id = {FIRST_BLOCK}")],
                       ("export", "calibrate"), "column current_a"),
    "a NaN time": ([_sql(f"UPDATE sample_blocks SET t_s = CAST(X'000000000000F87F' || substr(t_s, 9) "
                         f"AS BLOB) WHERE id = {FIRST_BLOCK}")], ("calibrate", "report"),
                   "column t_s holds a sample of nan"),
    "text in a numeric column": ([_sql("UPDATE steps SET command = 'abc' WHERE idx = 2")],
                                 ("show", "export", "calibrate"), "point 2, steps.command"),
    "an infinite point summary": ([_sql("UPDATE steps SET thrust_all_max_n = 9e999 WHERE idx = 1")],
                                  ("show", "export"), "point 1, steps.thrust_all_max_n"),
    "an infinite event time": ([_sql("UPDATE events SET t_s = 9e999")], ("show", "export"),
                               "events.t_s"),
    "Infinity in metadata_json": ([_sql(
        "UPDATE runs SET metadata_json = '{\"propeller_diameter_m\": Infinity}'")],
        ("show", "calibrate"), "propeller_diameter_m"),
    "NaN in actuator_json": ([_sql(
        "UPDATE runs SET actuator_json = '{\"command_unit\": \"percent\", \"neutral\": NaN, "
        "\"command_min\": -100, \"command_max\": 100}'")], ("calibrate", "export"),
        "runs.actuator_json"),
    "a blob in a numeric column": ([_sql("UPDATE steps SET t_end_s = X'00' WHERE idx = 0")],
                                   ("report",), "steps.t_end_s"),
    "garbage protocol_json": ([_sql("UPDATE runs SET protocol_json = 'not json'")],
                              ("show", "export"), "runs.protocol_json"),
    "plan_json nested 100,000 deep": ([_sql("UPDATE runs SET plan_json = ?",
                                            "[" * 100_000 + "]" * 100_000)],
                                      ("show", "report"), "runs.plan_json"),
    "rig_json a list": ([_sql("UPDATE runs SET rig_json = '[]'")], ("calibrate",), "runs.rig_json"),
    "actuator_json of the wrong shape": ([_sql(
        "UPDATE runs SET actuator_json = '{\"command_unit\": 5, \"neutral\": 0, "
        "\"command_min\": 0, \"command_max\": 1}'")], ("show",), "runs.actuator_json"),
    "metadata_json with a text number": ([_sql(
        "UPDATE runs SET metadata_json = '{\"propeller_diameter_m\": \"abc\"}'")], ("export",),
        "propeller_diameter_m"),
    "a text pid of a running run": ([_sql("UPDATE runs SET pid = 'abc', status = 'running'")],
                                    ("show",), "runs.pid"),
    "an unknown status": ([_sql("UPDATE runs SET status = 'hacked'")], ("report",),
                          "runs.status"),
    "a 100 kB run name": ([_sql("UPDATE runs SET name = ?", "x" * 100_000)], ("show",),
                          "runs.name"),
    "a name that is not UTF-8": ([_sql("UPDATE runs SET name = CAST(X'ff41' AS TEXT)")],
                                 ("export",), "not UTF-8"),
    "tare bias of text": ([_sql("UPDATE events SET detail_json = '{\"bias\": \"abc\"}' "
                                "WHERE kind = 'tare'")], ("calibrate",), "events.detail_json"),
    "counters of the wrong shape": ([_sql("UPDATE steps SET counters_json = '{\"netft\": 5}'")],
                                    ("show",), "steps.counters_json"),
    "a calibration summary that is a list": ([_sql("UPDATE calibrations SET summary_json = '[]'")],
                                             ("report", "export-all"), "summary_json"),
    "a garbage calibration state": ([_sql("UPDATE calibrations SET state = X'504b0304deadbeef'")],
                                    ("report", "export-cal"), "calibrations.state"),
    "a 400 MB blob": ([*QUICK_WRITE, _sql(f"UPDATE sample_blocks SET fx = zeroblob(400000000) "
                                          f"WHERE id = {FIRST_BLOCK}")], ("export",),
                      "sample_blocks.fx"),
}


@pytest.mark.parametrize("case", list(FIELDS))
def test_crafted_fields_end_in_exit_2(base, tmp_path, case):
    statements, commands, field = FIELDS[case]
    db = _crafted(base.db, tmp_path / "crafted.sqlite", *statements)
    before = _digest(db)
    for command in commands:
        line, _ = _cli(tmp_path, *_command(command, db, base.run_id, tmp_path / "out"))
        assert field in line and str(db) in line, line
        assert _digest(db) == before, command
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").rglob("*.*"))


def test_a_refused_export_leaves_an_earlier_export_whole(base, tmp_path):
    """The tables are staged and renamed together: a bad sample found in the second table no
    longer deletes the first table's file of an earlier, complete export."""
    db = shutil.copyfile(base.db, tmp_path / "good.sqlite")
    out = tmp_path / "out"
    assert run_cli("export", base.run_id, "--db", db, "--out", out, cwd=tmp_path).returncode == 0
    before = {p.name: _digest(p) for p in out.iterdir()}
    assert len(before) == 3
    bad = _crafted(db, tmp_path / "bad.sqlite", _sql(
        f"UPDATE sample_blocks SET thrust_n = CAST(X'000000000000F07F' || substr(thrust_n, 9) "
        f"AS BLOB) WHERE id = {FIRST_BLOCK}"))
    line, _ = _cli(tmp_path, "export", base.run_id, "--db", bad, "--out", out)
    assert "thrust_n" in line
    assert {p.name: _digest(p) for p in out.iterdir()} == before


def test_export_cal_never_takes_a_folder_from_the_state_blob(base, tmp_path):
    """A state blob whose calibration names another run: refused, nothing written anywhere."""
    blob = _state_of_run(base.db, "../../evil")
    db = _crafted(base.db, tmp_path / "crafted.sqlite",
                  _sql("UPDATE calibrations SET state = ?", blob))
    line, _ = _cli(tmp_path, *_command("export-cal", db, base.run_id, tmp_path / "out"))
    assert "calibration of run '../../evil'" in line
    assert {p.name for p in tmp_path.rglob("*")} <= {db.name, db.name + "-wal", db.name + "-shm"}


def test_export_cal_refuses_a_run_id_outside_the_grammar(base, tmp_path):
    statements = [_sql(f"UPDATE {table} SET {column} = '../../x' WHERE {column} = ?", base.run_id)
                  for table, column in (("runs", "id"), ("steps", "run_id"),
                                        ("events", "run_id"), ("calibrations", "run_id"))]
    db = _crafted(base.db, tmp_path / "crafted.sqlite", *statements)
    line, _ = _cli(tmp_path, *_command("export-cal", db, "..", tmp_path / "out"))
    assert "'../../x'" in line and "runs.id" in line
    assert not (tmp_path / "out").exists()


# -- merge sources, through the CLI -------------------------------------------------------
def _duplicated_runs() -> list[tuple[str, tuple]]:
    """Statements giving the runs table no primary key and every run twice."""
    cols = ", ".join(RUN_COLUMNS)
    return [_sql("ALTER TABLE runs RENAME TO old_runs"),
            _sql(f"CREATE TABLE runs ({cols})"),
            _sql(f"INSERT INTO runs ({cols}) SELECT {cols} FROM old_runs"),
            _sql(f"INSERT INTO runs ({cols}) SELECT {cols} FROM old_runs"),
            _sql("DROP TABLE old_runs")]


SOURCES = {
    "a view named like a table": ([_sql("ALTER TABLE events RENAME TO real_events"),
                                   _sql("CREATE VIEW events AS SELECT * FROM real_events")],
                                  "view 'events'"),
    "a 50 M-row view": ([_sql("CREATE VIEW big AS WITH RECURSIVE c(x) AS (SELECT 1 UNION ALL "
                              "SELECT x + 1 FROM c WHERE x < 50000000) SELECT x FROM c")],
                        "view 'big'"),
    "an extra table": ([_sql("CREATE TABLE extra (x)")], "table 'extra'"),
    "a trigger": ([_sql("CREATE TRIGGER t AFTER INSERT ON runs BEGIN SELECT 1; END")],
                  "trigger 't'"),
    "another schema version": ([_sql("PRAGMA user_version = 99")], "schema version 99"),
    "duplicate run ids": (_duplicated_runs(), "index sqlite_autoindex_runs_1"),
    "a run id that is a path": ([_sql("UPDATE runs SET id = '../../x'")], "runs.id"),
    "garbage plan_json": ([_sql("UPDATE runs SET plan_json = '{oops'")], "runs.plan_json"),
    "n=10^12 in a block": ([_sql(f"UPDATE sample_blocks SET n = 1000000000000 WHERE id = "
                                 f"{FIRST_BLOCK}")], "sample_blocks.n"),
    "blocks that do not add up": ([_sql("UPDATE steps SET n = 5 WHERE idx = 3")],
                                  "point 3, steps.n"),
    "text in a numeric column": ([_sql("UPDATE steps SET rate_hz = 'fast'")], "steps.rate_hz"),
    "an infinite point summary": ([_sql("UPDATE steps SET current_all_mean_a = -9e999")],
                                  "steps.current_all_mean_a"),
    "an infinite event time": ([_sql("UPDATE events SET t_s = -9e999")], "events.t_s"),
    "Infinity in a plan": ([_sql("UPDATE runs SET plan_json = replace(plan_json, "
                                 "'\"command\": -100.0', '\"command\": Infinity')")],
                           "runs.plan_json"),
    "a 400 MB blob": ([*QUICK_WRITE, _sql(f"UPDATE sample_blocks SET seq = zeroblob(400000000) "
                                          f"WHERE id = {FIRST_BLOCK}")], "sample_blocks.seq"),
}


def _source_state(path: Path) -> tuple[str, int, set[str]]:
    """A merge source's bytes, mtime and the files beside it."""
    return _digest(path), path.stat().st_mtime_ns, {p.name for p in path.parent.iterdir()}


@pytest.mark.parametrize("case", list(SOURCES))
def test_crafted_merge_sources_are_refused_and_merge_nothing(base, tmp_path, case):
    statements, field = SOURCES[case]
    folder = tmp_path / "src"
    folder.mkdir()
    good = shutil.copyfile(base.other, folder / "good.sqlite")
    bad = _crafted(base.db, folder / "bad.sqlite", *statements)
    target = shutil.copyfile(base.empty, tmp_path / "lab.sqlite")
    sources, before = _source_state(bad), _digest(target)
    line, _ = _cli(tmp_path, "merge", good, bad, "-o", target)
    assert field in line and "nothing was merged" in line, line
    assert _digest(target) == before
    assert _source_state(bad) == sources


def test_a_file_that_is_no_database_is_refused(base, tmp_path):
    junk = tmp_path / "junk.sqlite"
    junk.write_bytes(b"SQLite format 3\x00" + bytes(range(256)) * 64)
    target = shutil.copyfile(base.empty, tmp_path / "lab.sqlite")
    before = _digest(target)
    line, _ = _cli(tmp_path, "merge", junk, "-o", target)
    assert "junk.sqlite" in line and _digest(target) == before


def test_merge_reads_its_source_without_touching_it(base, tmp_path):
    folder = tmp_path / "src"
    folder.mkdir()
    source = shutil.copyfile(base.db, folder / "rig.sqlite")
    target = shutil.copyfile(base.empty, tmp_path / "lab.sqlite")
    before = _source_state(source)
    assert main(["merge", str(source), "-o", str(target)]) == 0
    assert _source_state(source) == before  # no -wal, no -shm, same bytes and mtime
    with Store(target, read_only=True) as store:
        assert store.run_ids() == [base.run_id]


# -- calibration folders, through the API -------------------------------------------------
def _folder(base: Base, tmp_path: Path, **files: bytes) -> Path:
    """A copy of the base calibration folder with some files replaced (name_ext=bytes)."""
    folder = tmp_path / "folder"
    shutil.copytree(base.folder, folder, dirs_exist_ok=True)
    for name, data in files.items():
        (folder / name.replace("_json", ".json").replace("_csv", ".csv")).write_bytes(data)
    return folder


def _document(base: Base) -> dict:
    """The base calibration.json, parsed."""
    return json.loads((base.folder / "calibration.json").read_text())


FOLDER_FILES = {
    "not JSON": ("calibration_json", b"{'format': 1}", "not valid JSON"),
    "a JSON list": ("calibration_json", b"[1, 2]", "expected an object"),
    "not UTF-8": ("calibration_json", b'{"format": "\xff"}', "not UTF-8"),
    "nested 100,000 deep": ("calibration_json", b"[" * 100_000 + b"]" * 100_000, "nested"),
    "too large": ("calibration_json", b" " * (MAX_JSON_BYTES + 1), "too large"),
    "a CSV not UTF-8": ("command_curve_csv", b"depth_m,command\n\xff\xfe,1\n", "not UTF-8"),
    "a CSV without its columns": ("inverse_lut_csv", b"a,b\n1,2\n", "no column 'depth_m'"),
    "a CSV with a column twice": ("command_curve_csv",
                                  b"depth_m,command,thrust_fit_n,command\n1,2,3,4\n",
                                  "appears twice"),
    "a CSV 100,000 columns wide": ("command_curve_csv", b",".join([b"c"] * 100_000) + b"\n",
                                   "more than 64 columns"),
}


@pytest.mark.parametrize("case", list(FOLDER_FILES))
def test_crafted_calibration_files_are_usage_errors(base, tmp_path, case):
    name, data, problem = FOLDER_FILES[case]
    folder = _folder(base, tmp_path, **{name: data})
    with pytest.raises(UsageError) as info:
        rigtool.load_calibration(folder)
    message = str(info.value)
    assert problem in message and str(folder) in message and "\n" not in message, message


@pytest.mark.parametrize(("path", "value", "problem"), [
    (("depths", 0, "coefficients", "C_p_fwd", "value"), "abc", "depths[0].coefficients.C_p_fwd."
                                                               "value: expected a number"),
    (("depths",), {"a": 1}, "depths: expected an array"),
    (("format",), "something-else", "format:"),
    (("dynamics",), {"selected": "x", "models": {}, "levels": []}, "dynamics.selected"),
    (("voltage_laws",), [{"k": 1, "b": {}}], "voltage_laws[0].k: expected an object"),
])
def test_calibration_json_fields_are_checked_by_name(base, tmp_path, path, value, problem):
    doc = _document(base)
    _put(doc, path, value)
    folder = _folder(base, tmp_path, calibration_json=json.dumps(doc).encode())
    with pytest.raises(UsageError, match="calibration.json: " + re.escape(problem)):
        rigtool.load_calibration(folder)


def _put(doc: object, path: tuple, value: object) -> None:
    """Set the value at `path` in a JSON document."""
    for key in path[:-1]:
        doc = doc[key]  # type: ignore[index]
    doc[path[-1]] = value  # type: ignore[index]


def test_the_checked_format_and_bounds_are_the_written_ones():
    from rigtool import bounds, readback
    from rigtool.artefacts.calibration import FORMAT
    from rigtool.store import RUN_STATUSES

    assert CALIBRATION_FORMAT == FORMAT
    assert RUN_COLUMNS["status"].choices == RUN_STATUSES
    for name in ("MAX_COMMAND", "MAX_SAMPLES_PER_POINT", "MAX_SEED"):
        assert getattr(readback, name) == getattr(bounds, name), name
    assert readback.MAX_STORED_POINTS >= bounds.MAX_POINTS


# -- fuzzing through the API ----------------------------------------------------------------
SCALARS = (st.none() | st.booleans() | st.integers(-(2**70), 2**70)
           | st.floats(allow_nan=True) | st.text(max_size=20))
JSON_VALUES = st.recursive(SCALARS, lambda inner: st.lists(inner, max_size=4)
                           | st.dictionaries(st.text(max_size=8), inner, max_size=4),
                           max_leaves=12)
JSON_TEXTS = JSON_VALUES.map(json.dumps) | st.sampled_from([
    "[" * 5_000 + "]" * 5_000, "{" * (MAX_JSON_DEPTH + 1), "[]", "{}", "null", "1e999",
    '{"bias": [1, "x"]}', '{"a": {"b": "c"}}', "9" * 5_000])
SQL_VALUES = (st.none() | st.integers(-(2**63), 2**63 - 1)
              | st.sampled_from([10**12, -1, 0, 65_536, 65_537, 2**62])
              | st.floats(allow_nan=False) | st.text(max_size=30) | st.binary(max_size=80)
              | JSON_TEXTS)
TABLE_COLUMNS = ([("runs", c) for c in RUN_COLUMNS] + [("steps", c) for c in STEP_COLUMNS]
                 + [("events", c) for c in EVENT_COLUMNS]
                 + [("calibrations", c) for c in CALIBRATION_COLUMNS]
                 + [("sample_blocks", c) for c in ("chunk", "n", *SAMPLE_COLUMNS[1:])])


def _corrupt(source: Path, target: Path, table: str, column: str, row: int,
             value: object) -> Path:
    """`source` copied with one value replaced; hypothesis rejects what SQLite refuses."""
    try:
        return _crafted(source, target, _sql(
            f"UPDATE {table} SET {column} = ? WHERE rowid = (SELECT rowid FROM {table} "
            f"ORDER BY rowid LIMIT 1 OFFSET ?)", value, row))
    except (sqlite3.IntegrityError, sqlite3.InterfaceError, sqlite3.OperationalError,
            OverflowError, UnicodeEncodeError):
        reject()


def _example_dir(tmp_path: Path) -> Path:
    """A fresh folder for one hypothesis example (they share the test's tmp_path)."""
    return Path(tempfile.mkdtemp(dir=tmp_path))


def _read_everything(db: Path, out: Path) -> None:
    """Every reader of a stored run the API and `export` use."""
    with rigtool.open(db) as lab:
        lab.runs()
        run = lab.run("last")
        run.points()
        run.samples()
        run.events()
        lab.store.transport_counters(run.id)
        export_run(lab.store, run.id, out)
        lab.calibration(run)


@FUZZ
@given(target=st.sampled_from(TABLE_COLUMNS), row=st.integers(0, 3), value=SQL_VALUES)
def test_fuzzed_fields_read_cleanly_or_raise_rigtool_errors(base, tmp_path, target, row, value):
    work = _example_dir(tmp_path)
    db = _corrupt(base.db, work / "fuzz.sqlite", *target, row, value)
    before = _digest(db)
    try:
        _read_everything(db, work / "export")
        event("read")
    except RigtoolError as exc:
        event(f"refused: {type(exc).__name__}")
        assert "\n" not in str(exc), str(exc)
    assert _digest(db) == before


@FUZZ
@given(target=st.sampled_from(TABLE_COLUMNS), row=st.integers(0, 3), value=SQL_VALUES)
def test_fuzzed_merge_sources_merge_checked_rows_or_nothing(base, tmp_path, target, row, value):
    work = _example_dir(tmp_path)
    (work / "src").mkdir()
    source = _corrupt(base.db, work / "src" / "source.sqlite", *target, row, value)
    lab = shutil.copyfile(base.empty, work / "lab.sqlite")
    sources, before = _source_state(source), _digest(lab)
    with Store(lab) as store:
        try:
            store.merge_from([source])
            event("merged")
        except (DataError, UsageError) as exc:
            event(f"refused: {type(exc).__name__}")
            assert _digest(lab) == before
    assert _source_state(source) == sources
    _read_merged(lab, work / "export")


def _read_merged(lab: Path, out: Path) -> None:
    """What a merge added reads cleanly, or is a rigtool error like any stored run."""
    with contextlib.suppress(RigtoolError):
        _read_everything(lab, out)


def _paths(doc: object, prefix: tuple = ()) -> list[tuple]:
    """Every path into a JSON document."""
    out = [prefix]
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc[:3]):
            out += _paths(v, (*prefix, i))
    return out


@FUZZ
@given(data=st.data(), value=JSON_VALUES)
def test_fuzzed_calibration_documents_load_or_raise_usage_errors(base, tmp_path, data, value):
    doc = _document(base)
    path = data.draw(st.sampled_from([p for p in _paths(doc) if p]))
    _put(doc, path, value)
    folder = _folder(base, _example_dir(tmp_path), calibration_json=json.dumps(doc).encode())
    try:
        cal = rigtool.load_calibration(folder)
    except UsageError as exc:
        event("refused")
        assert str(folder) in str(exc)
        return
    event("loaded")
    _use(cal)


def _use(cal: rigtool.api.Calibration) -> None:
    """The calibration's readers that need no argument from the caller."""
    cal.thrust(20.0)
    cal.command(1.0)
    cal.coefficients  # noqa: B018
    cal.voltages  # noqa: B018
    cal.voltage_laws  # noqa: B018
    dynamics = cal.dynamics
    if dynamics is not None:
        repr(dynamics)
    cal.thrust_from_speed(100.0)
    cal.thrust_from_current(2.0)


@FUZZ
@given(name=st.sampled_from(["command_curve.csv", "inverse_lut.csv"]), data=st.data())
def test_fuzzed_calibration_csvs_load_or_raise_usage_errors(base, tmp_path, name, data):
    lines = (base.folder / name).read_bytes().splitlines(keepends=True)
    i = data.draw(st.integers(0, len(lines) - 1))
    lines[i] = data.draw(st.binary(max_size=60) | st.text(max_size=60).map(str.encode))
    folder = _folder(base, _example_dir(tmp_path), **{name.replace(".", "_"): b"".join(lines)})
    try:
        cal = rigtool.load_calibration(folder)
    except UsageError as exc:
        event("refused")
        assert str(folder) in str(exc)
        return
    event("loaded")
    _use(cal)


def test_a_refused_merge_creates_no_target(tmp_path, capsys):
    junk = tmp_path / "junk.sqlite"
    junk.write_bytes(b"not a database at all" * 100)
    target = tmp_path / "lab.sqlite"
    assert main(["merge", str(junk), "-o", str(target)]) == 2
    assert "nothing was merged" in capsys.readouterr().err
    assert not target.exists() and not list(tmp_path.glob("lab.sqlite-*"))
