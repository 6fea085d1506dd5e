"""Hostile input to `rigtool import`: clear errors (exit 2 or file:line), never a traceback."""

from __future__ import annotations

import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rigtool import store as store_module
from rigtool.cli import main
from rigtool.spool import SampleSpool
from rigtool.store import Store
from rigtool.store.connection import Transaction

GOOD = "t,cmd,F\n0,1500,0\n1,1600,1.0\n2,1700,2.0\n3,1800,3.0\n"
COLS = ["--col", "command=cmd", "--col", "thrust=F", "--col", "time=t", "--command-unit", "pulse_us"]


def _import(tmp_path: Path, text: str, *options: str) -> tuple[int, str, str, Path]:
    """Run `rigtool import` on `text` through the CLI; return (status, stdout, stderr, db)."""
    data = tmp_path / "data.csv"
    data.write_text(text)
    db = tmp_path / "runs.sqlite"
    proc = subprocess.run([sys.executable, "-m", "rigtool.cli", "import", str(data), *options,
                           "--db", str(db)], capture_output=True, text=True, timeout=60)
    assert "Traceback" not in proc.stderr, proc.stderr
    return proc.returncode, proc.stdout, proc.stderr, db


def _n_runs(db: Path) -> int:
    if not db.exists():
        return 0
    with sqlite3.connect(db) as conn:
        return conn.execute("SELECT count(*) FROM runs").fetchone()[0]


@pytest.mark.parametrize(("option", "value", "words"), [
    ("--delimiter", ";;", "--delimiter"),
    ("--delimiter", "", "--delimiter"),
    ("--delimiter", '"', "--delimiter"),
    ("--settle-s", "nan", "--settle-s"),
    ("--settle-s", "inf", "--settle-s"),
    ("--pole-pairs", "0", "--pole-pairs"),
    ("--neutral", "nan", "--neutral"),
    ("--depth", "inf", "--depth"),
    ("--col", "thrust=²", "no column"),
    ("--col", "thrust=" + "9" * 5000, "--col"),
    ("--thruster-id", "t200\x1b[2J", "U+001B"),
    # issue 49's attack report: ids the dataset cannot file as a folder were stored
    ("--thruster-id", "t" * 244, "could not file the run"),
    ("--thruster-id", "é" * 122, "could not file the run"),
    ("--name", "run\u2066one", "U+2066"),
])
def test_bad_option_is_a_usage_error(tmp_path: Path, option: str, value: str, words: str) -> None:
    cols = COLS[:2] + COLS[4:] if option == "--col" else COLS
    status, _, err, db = _import(tmp_path, GOOD, *cols, f"{option}={value}")
    assert status == 2, err
    assert words in err
    assert _n_runs(db) == 0


def test_huge_cell_is_a_bad_row_with_its_line(tmp_path: Path) -> None:
    text = "t,cmd,F\n0,1500,0\n1,1600," + "1" * 300_000 + "\n2,1700,2\n3,1800,3\n"
    status, out, err, _ = _import(tmp_path, text, *COLS)
    assert status == 0, err
    assert "data.csv:3:" in err and "characters" in err
    assert len(err) < 2000  # the cell itself is not echoed
    assert "3 row(s) read, 1 skipped" in out


def test_long_but_readable_cell_is_not_echoed_whole(tmp_path: Path) -> None:
    text = "t,cmd,F\n0,1500,0\n1,1600," + "x" * 100_000 + "\n2,1700,2\n3,1800,3\n"
    status, out, err, _ = _import(tmp_path, text, *COLS)
    assert status == 0, err
    assert "data.csv:3: thrust:" in err and len(err) < 2000
    assert "3 row(s) read, 1 skipped" in out


@pytest.mark.parametrize("cell", ["1e400", "-1e400", "1e308"])
def test_overflow_is_a_bad_row_with_its_line(tmp_path: Path, cell: str) -> None:
    status, out, err, db = _import(tmp_path, GOOD.replace("1.0", cell), *COLS, "--unit", "thrust=kgf")
    assert status == 0, err
    assert "data.csv:3: thrust:" in err
    assert "3 row(s) read, 1 skipped" in out
    with sqlite3.connect(db) as conn:
        assert conn.execute("SELECT count(*) FROM steps WHERE thrust_all_mean_n IS NULL").fetchone() == (0,)


def test_overflowing_std_is_a_bad_row(tmp_path: Path) -> None:
    text = "cmd,F,s,n\n1500,0,0.1,5\n1600,1e308,1e308,5\n1700,2,0.1,5\n"
    status, out, err, _ = _import(tmp_path, text, "--col", "command=cmd", "--col", "thrust=F",
                                  "--col", "thrust_std=s", "--col", "n_samples=n",
                                  "--command-unit", "pulse_us")
    assert status == 0, err
    assert "data.csv:3:" in err and "2 row(s) read, 1 skipped" in out


@pytest.mark.parametrize("header", ["t,cmd,F,F", "t,cmd,F,f", "t,cmd,F (N),F [kgf]"])
def test_duplicate_header_is_a_usage_error(tmp_path: Path, header: str) -> None:
    text = header + "\n0,1500,0,5\n1,1600,1,6\n2,1700,2,7\n"
    status, _, err, db = _import(tmp_path, text, *COLS)
    assert status == 2, err
    assert "F" in err and "ambiguous" in err and "column number" in err
    assert _n_runs(db) == 0


def test_duplicate_recognised_header_is_a_usage_error(tmp_path: Path) -> None:
    text = "Time (s),ESC signal (µs),Thrust (kgf),Thrust (kgf)\n0,1500,0,0\n1,1600,1,1\n"
    status, _, err, _ = _import(tmp_path, text)
    assert status == 2 and "ambiguous" in err


def test_duplicate_header_in_an_unused_column_is_fine(tmp_path: Path) -> None:
    text = "t,cmd,F,note,note\n0,1500,0,a,b\n1,1600,1,a,b\n2,1700,2,a,b\n"
    status, out, err, _ = _import(tmp_path, text, *COLS)
    assert status == 0, err
    assert "3 row(s) read, 0 skipped" in out


def test_many_points_are_written_in_few_transactions(tmp_path: Path, monkeypatch) -> None:
    n = 5000
    rows = "\n".join(f"{i / 1000:.3f},{1100 + 800 * i / n:.4f},{i / n:.4f}" for i in range(n))
    data = tmp_path / "ramp.csv"
    data.write_text("t,cmd,F\n" + rows + "\n")
    count = {"n": 0}
    enter = Transaction.__enter__

    def counting(self):
        count["n"] += 1
        return enter(self)

    db = tmp_path / "runs.sqlite"
    Store(db).close()  # schema migrations are not the import's transactions
    monkeypatch.setattr(Transaction, "__enter__", counting)
    # --format points: a point per row (auto bins this ramp into command bins).
    assert main(["import", str(data), *COLS, "--format", "points", "--db", str(db)]) == 0
    assert count["n"] <= 10
    store = Store(db, create=False)
    run_id = store.resolve_run_id("last")
    assert store.run(run_id)["status"] == "completed"
    steps = store.steps(run_id)
    assert len(steps) == n and steps[-1]["n"] == 1
    assert steps[-1]["thrust_all_mean_n"] == pytest.approx((n - 1) / n)


KILL_AFTER_COMMIT = """\
import os, sys
from rigtool.store import connection, writer
writer.IMPORT_ROWS_PER_TRANSACTION = 500
_exit = connection.Transaction.__exit__
_count = [0]
def _dies(self, *exc):
    result = _exit(self, *exc)
    _count[0] += 1
    if _count[0] == {n}:
        os._exit(9)  # like SIGKILL: no cleanup runs
    return result
connection.Transaction.__exit__ = _dies
from rigtool.cli import main
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.parametrize("kill_after", [1, 2, 3])
def test_killed_import_is_marked_and_resume_refuses(tmp_path: Path, kill_after: int) -> None:
    n = 3000
    rows = "\n".join(f"{i / 1000:.3f},{1100 + 800 * i / n:.4f},{i / n:.4f}" for i in range(n))
    data = tmp_path / "ramp.csv"
    data.write_text("t,cmd,F\n" + rows + "\n")
    db = tmp_path / "runs.sqlite"
    Store(db).close()
    script = tmp_path / "killed.py"
    script.write_text(KILL_AFTER_COMMIT.replace("{n}", str(kill_after)))
    proc = subprocess.run([sys.executable, str(script), "import", str(data), *COLS, "--db", str(db)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 9, proc.stderr
    store = Store(db, create=False)
    runs = store.runs()
    if not runs:
        return  # a killed import may leave nothing at all
    (run,) = runs
    full = store.run(run["id"])
    assert full["status"] == "failed" and "incomplete import" in full["stop_reason"]
    store.close()
    resume = subprocess.run([sys.executable, "-m", "rigtool.cli", "sweep", "--resume", "last",
                             "--db", str(db)], capture_output=True, text=True, timeout=60)
    assert resume.returncode == 2, resume.stderr
    assert "Traceback" not in resume.stderr
    assert "incomplete import" in resume.stderr and "rigtool import" in resume.stderr


def test_resume_refuses_an_import_left_interrupted_by_an_older_rigtool(tmp_path: Path) -> None:
    data = tmp_path / "d.csv"
    data.write_text(GOOD)
    db = tmp_path / "runs.sqlite"
    assert main(["import", str(data), *COLS, "--db", str(db)]) == 0
    with sqlite3.connect(db) as conn:
        conn.execute("UPDATE runs SET status = 'interrupted', stop_reason = 'the sweep process "
                     "ended without closing the run'")
    resume = subprocess.run([sys.executable, "-m", "rigtool.cli", "sweep", "--resume", "last",
                             "--db", str(db)], capture_output=True, text=True, timeout=60)
    assert resume.returncode == 2 and "Traceback" not in resume.stderr, resume.stderr
    assert "import" in resume.stderr


def test_stats_of_bulk_points_match_single_points(db_path: Path) -> None:
    rng = np.random.default_rng(3)
    sizes = [1, 2, 5, 1, 7]
    bounds = np.concatenate(([0], np.cumsum(sizes)))
    n = int(bounds[-1])
    thrust = rng.normal(size=n)
    thrust[3] = np.nan
    speed = np.full(n, np.nan)
    speed[bounds[2]:bounds[3]] = rng.normal(size=sizes[2])
    stats = store_module.segment_stats(thrust, bounds)
    for i in range(len(sizes)):
        part = thrust[bounds[i]:bounds[i + 1]]
        one = SampleSpool.of({"t_s": np.zeros(part.size), "thrust_n": part}, ("t_s", "thrust_n"),
                             ("thrust_n",))
        expect = dict(zip(("mean", "std", "min", "max"), one.stats("thrust_n") or (None,) * 4,
                          strict=True))
        got = {k: v[i] for k, v in stats.items()}
        for k in ("mean", "std", "min", "max"):
            e, g = expect[k], got[k]
            assert (e is None and g is None) or g == pytest.approx(e, rel=1e-12, abs=1e-15)
    speed_stats = store_module.segment_stats(speed, bounds)
    assert speed_stats["mean"][0] is None and speed_stats["mean"][2] is not None


def test_huge_synthesised_table_is_refused(tmp_path: Path) -> None:
    rows = "\n".join(f"{1100 + i},{i / 100:.2f},0.1,10000" for i in range(1100))
    status, _, err, db = _import(tmp_path, "cmd,F,s,n\n" + rows + "\n", "--col", "command=cmd",
                                 "--col", "thrust=F", "--col", "thrust_std=s",
                                 "--col", "n_samples=n", "--command-unit", "pulse_us")
    assert status == 2 and "samples" in err, err
    assert _n_runs(db) == 0


def test_many_dropped_points_give_a_bounded_warning_list(tmp_path: Path) -> None:
    rows = "\n".join(f"{i * 0.01:.2f},{1100 + i},{i / 100:.2f}" for i in range(3000))
    rows += "\n" + "\n".join(f"{30 + i * 0.01:.2f},1900,5" for i in range(300))
    status, out, err, _ = _import(tmp_path, "t,cmd,F\n" + rows + "\n", *COLS, "--format",
                                  "timeseries", "--settle-s", "1")
    assert status == 0, err
    assert "inside the 1 s settling time" in err
    assert err.count("\n") < 40
    assert "1 point(s)" in out


def test_two_rows_on_one_line_are_a_bad_row_and_a_note_is_not(tmp_path: Path) -> None:
    """A line holding two rows run together (a lost line end) has numbers beyond the header's
    columns: skipped and named, not read as a row whose cells happen to fit. Empty trailing
    cells and a text note after the last column leave a row as it is."""
    text = ("t,cmd,F\n0,1500,0\n1,1600,1.0,\n2,1700,2.03,1800,3.0\n"
            "4,1900,4.0,operator note\n5,2000,5.0\n")
    status, out, err, db = _import(tmp_path, text, *COLS)
    assert status == 0
    assert "data.csv:4: row has 5 cells, the header 3, with numbers beyond it" in err
    assert "4 row(s) read, 1 skipped" in out
    with Store(db, create=False) as store:
        (run_id,) = store.run_ids()
        assert [s["command"] for s in store.steps(run_id)] == [1500, 1600, 1900, 2000]


def test_a_column_without_a_name_is_not_two_rows_on_one_line(tmp_path: Path) -> None:
    """A logger that writes one more (numeric) cell than its header names on every row has a
    column without a name, not rows run together: its rows are read, the cells ignored."""
    text = "t,cmd,F\n0,1500,0,7\n1,1600,1.0,7\n2,1700,2.0,7\n3,1800,3.0\n"
    status, out, err, db = _import(tmp_path, text, *COLS)
    assert status == 0 and "4 row(s) read, 0 skipped" in out, (out, err)
