"""End to end through the CLI on the simulator: sweep, runs, show."""

from __future__ import annotations

import subprocess
import sys

from rigtool.cli import main
from rigtool.store import Store

from .conftest import PROTOCOLS, copy_db


def test_quick_demo_sweep_runs_and_show(capsys, db_path):
    assert main(["sweep", str(PROTOCOLS / "quick-demo.yaml"), "--sim", "--db", str(db_path)]) == 0
    assert "completed: 42/42 points" in capsys.readouterr().out
    assert main(["runs", "--db", str(db_path)]) == 0
    assert "quick-demo" in capsys.readouterr().out
    assert main(["show", "last", "--db", str(db_path)]) == 0
    text = capsys.readouterr().out
    assert "status completed" in text and "samples: 42,000" in text and "per-depth summary" in text
    assert "actuator: neutral 0 %, range -100 .. 100 %" in text


def test_seed_is_stored_and_reproducible(db_path):
    for _ in range(2):
        assert main(["sweep", str(PROTOCOLS / "quick-demo.yaml"), "--sim", "--seed", "99",
                     "--db", str(db_path)]) == 0
    store = Store(db_path)
    runs = store.runs()
    assert [store.run(r["id"])["seed"] for r in runs] == [99, 99]
    a, b = (store.samples(r["id"], ["thrust_n"])["thrust_n"] for r in runs)
    assert (a == b).all()


def test_subprocess_sweep_prints_progress_and_exit_status(tmp_path):
    db = tmp_path / "r.sqlite"
    proc = subprocess.run(
        [sys.executable, "-m", "rigtool.cli", "sweep", str(PROTOCOLS / "quick-demo.yaml"), "--sim",
         "--db", str(db)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "point 42/42" in proc.stderr




def test_progress_names_the_supply_voltage_of_the_pass(tmp_path):
    """A sweep at several supply voltages says in each progress line which one is set."""
    text = (PROTOCOLS / "voltage-sweep.yaml").read_text().replace(
        "range: {start: 1100, stop: 1900, step: 25}", "values: [1300, 1700]")
    protocol = tmp_path / "volts.yaml"
    protocol.write_text(text)
    proc = subprocess.run(
        [sys.executable, "-m", "rigtool.cli", "sweep", str(protocol), "--sim", "--db",
         str(tmp_path / "r.sqlite")], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.startswith("point ")]
    assert len(lines) == 10
    for i, line in enumerate(lines):
        assert f"supply {12 + 2 * (i // 2):5.1f} V" in line, line


def test_runs_says_which_runs_are_calibrated(capsys, tmp_path, shipped_sweep):
    db = str(copy_db(shipped_sweep("quick-demo"), tmp_path / "db.sqlite"))
    assert main(["sweep", str(PROTOCOLS / "quick-demo.yaml"), "--sim", "--db", db]) == 0
    with Store(db) as store:
        newer, older = (r["id"] for r in store.runs())
    assert main(["calibrate", older, "--db", db, "--out", str(tmp_path / "cal")]) == 0
    with Store(db) as store:
        when = store.latest_calibration(older)["created_utc"][:16].replace("T", " ")
    capsys.readouterr()
    assert main(["runs", "--db", db]) == 0
    text = capsys.readouterr().out
    assert "calibrated (UTC)" in text
    cells = {row[0]: row for row in ([c.strip() for c in line.split("│")[1:-1]]
                                     for line in text.splitlines()) if row}
    assert cells[older][-1] == when and cells[newer][-1] == "no"
