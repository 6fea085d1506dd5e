"""End to end through the CLI on the simulator: sweep, runs, show."""

from __future__ import annotations

import subprocess
import sys

from rigtool.cli import main
from rigtool.store import Store

from .conftest import PROTOCOLS


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


