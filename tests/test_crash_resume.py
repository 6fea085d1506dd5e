"""Crash consistency and resume: kill -9, SIGTERM and Ctrl-C on a real sweep process."""

from __future__ import annotations

import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from rigtool.cli import main
from rigtool.store import Store

from .conftest import SMALL_PROTOCOL

pytestmark = pytest.mark.usefixtures("terminal_signals")  # the sweeps are stopped by SIGINT and SIGTERM

N_POINTS = 41
MEDIUM = SMALL_PROTOCOL.replace(
    "values: [-50, 0, 50, 100]", "range: {start: -100, stop: 100, step: 5}"
).replace("rest_s: 0.2", "rest_s: 120.0").replace("max_thrust_n: 90", "max_thrust_n: 200")


def _start(protocol: Path, db: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "rigtool.cli", "sweep", str(protocol), "--sim", "--db", str(db)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for_steps(db: Path, n: int, proc: subprocess.Popen, timeout: float = 60.0) -> int:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert proc.poll() is None, "sweep ended before it could be interrupted"
        if db.exists():
            try:
                conn = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=1)
                count = conn.execute("SELECT count(*) FROM steps").fetchone()[0]
                conn.close()
                if count >= n:
                    return count
            except sqlite3.OperationalError:
                pass
        time.sleep(0.02)
    raise AssertionError("sweep made no progress")


def _check_whole(store: Store, run_id: str) -> list[dict]:
    assert store.conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    steps = store.steps(run_id)
    for s in steps:
        assert len(store.step_samples(s["id"], ["t_s", "thrust_n"])["thrust_n"]) == s["n"] == 200
    return steps


def _resume_and_check(db: Path, capsys) -> None:
    assert main(["sweep", "--resume", "last", "--db", str(db)]) == 0
    assert "completed" in capsys.readouterr().out
    store = Store(db)
    run_id = store.resolve_run_id("last")
    steps = _check_whole(store, run_id)
    assert [s["idx"] for s in steps] == list(range(N_POINTS))
    assert [s["command"] for s in steps] == [-100 + 5 * i for i in range(N_POINTS)]
    t = store.samples(run_id, ["t_s"])["t_s"]
    assert np.all(np.diff(t) > 0), "sample times must keep increasing across the resume"
    assert len(store.events(run_id, "resumed")) == 1
    assert store.run(run_id)["status"] == "completed"


@pytest.mark.slow
def test_kill_9_leaves_whole_points_and_resume_completes(write_yaml, tmp_path, capsys):
    db = tmp_path / "crash.sqlite"
    proc = _start(write_yaml(MEDIUM), db)
    _wait_for_steps(db, 5, proc)
    proc.kill()
    proc.wait(timeout=10)
    store = Store(db)  # opening the store notices the dead owner
    (run,) = store.runs()
    assert run["status"] == "interrupted"
    assert 5 <= len(_check_whole(store, run["id"])) < N_POINTS
    store.close()
    _resume_and_check(db, capsys)


@pytest.mark.slow
@pytest.mark.parametrize("sig, status, reason", [
    (signal.SIGTERM, 1, "SIGTERM"),
    (signal.SIGINT, 130, "Ctrl-C"),
])
def test_signals_abort_cleanly_and_resume(write_yaml, tmp_path, capsys, sig, status, reason):
    db = tmp_path / "sig.sqlite"
    proc = _start(write_yaml(MEDIUM), db)
    _wait_for_steps(db, 3, proc)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == status, err
    assert "Traceback" not in err and "actuator at neutral" in err and "--resume" in err
    store = Store(db)
    (run,) = store.runs()
    full = store.run(run["id"])
    assert full["status"] == "aborted" and reason in full["stop_reason"]
    _check_whole(store, run["id"])
    store.close()
    _resume_and_check(db, capsys)


def test_resume_refuses_completed_run(write_yaml, tmp_path, capsys):
    db = tmp_path / "done.sqlite"
    assert main(["sweep", str(write_yaml(SMALL_PROTOCOL)), "--sim", "--db", str(db)]) == 0
    assert main(["sweep", "--resume", "last", "--db", str(db)]) == 2
    assert "only interrupted, aborted, failed runs resume" in capsys.readouterr().err


def test_resume_is_claimed_once(write_yaml, tmp_path):
    from rigtool.errors import UsageError

    db = tmp_path / "twice.sqlite"
    store = Store(db)
    run_id = store.create_run(name="r", protocol={}, protocol_path=None, rig={}, plan=[], metadata={},
                              seed=1, command_unit="percent", tool_version="t")
    store.finish_run(run_id, "aborted", "test")
    store.reopen_run(run_id)
    with pytest.raises(UsageError, match="no longer resumable"):
        store.reopen_run(run_id)


def test_force_takes_over_a_run_left_running(write_yaml, tmp_path, capsys):
    db = tmp_path / "stuck.sqlite"
    assert main(["sweep", str(write_yaml(MEDIUM)), "--sim", "--db", str(db)]) == 0
    store = Store(db)
    run_id = store.resolve_run_id("last")
    last = store.steps(run_id)[-1]["id"]
    store.conn.execute("DELETE FROM sample_blocks WHERE step_id = ?", (last,))
    store.conn.execute("DELETE FROM steps WHERE id = ?", (last,))
    store.conn.execute("UPDATE runs SET status = 'running', pid = 1 WHERE id = ?", (run_id,))
    store.close()
    assert main(["sweep", "--resume", "last", "--db", str(db)]) == 2
    assert "only interrupted" in capsys.readouterr().err
    assert main(["sweep", "--resume", "last", "--force", "--db", str(db)]) == 0
    assert len(Store(db).steps(run_id)) == N_POINTS


def _cut_last_point(db: Path, ref: str = "last") -> str:
    """Make a run (default: the newest) look interrupted one point before its end."""
    store = Store(db)
    run_id = store.resolve_run_id(ref)
    last = store.steps(run_id)[-1]["id"]
    store.conn.execute("DELETE FROM sample_blocks WHERE step_id = ?", (last,))
    store.conn.execute("DELETE FROM steps WHERE id = ?", (last,))
    store.conn.execute("UPDATE runs SET status = 'interrupted' WHERE id = ?", (run_id,))
    store.close()
    return run_id


def test_resume_with_a_new_rig_file_and_its_db(write_yaml, tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("RIGTOOL_DB", raising=False)
    db = tmp_path / "lab.sqlite"
    rig = "rigtool_rig: 1\nname: {name}\ndb: " + str(db) + "\nsimulator: {{profile: {profile}}}\n"
    first, moved, other = (tmp_path / f"{n}.yaml" for n in ("first", "moved", "other"))
    first.write_text(rig.format(name="pool", profile="can-bldc"))
    moved.write_text(rig.format(name="pool-after-power-cut", profile="can-bldc"))
    other.write_text(rig.format(name="bench", profile="stm32-pwm"))
    assert main(["sweep", str(write_yaml(SMALL_PROTOCOL)), "--rig", str(first)]) == 0
    run_id = _cut_last_point(db)
    assert main(["sweep", "--resume", "last", "--rig", str(other)]) == 2
    assert "same drivers, thrust axis and mount" in capsys.readouterr().err
    assert main(["sweep", "--resume", "last", "--rig", str(moved)]) == 0  # db from the rig file
    store = Store(db)
    assert store.run(run_id)["status"] == "completed" and len(store.steps(run_id)) == 4
    assert store.events(run_id, "resumed")[0]["detail"]["rig"]["name"] == "pool-after-power-cut"


def test_last_is_the_resumed_run(write_yaml, tmp_path, capsys):
    db = tmp_path / "two.sqlite"
    protocol = str(write_yaml(SMALL_PROTOCOL))
    for _ in range(2):
        assert main(["sweep", protocol, "--sim", "--db", str(db)]) == 0
    older, newer = sorted(r["id"] for r in Store(db).runs())
    assert Store(db).resolve_run_id("last") == newer
    _cut_last_point(db, older)
    assert main(["sweep", "--resume", older, "--db", str(db)]) == 0
    assert Store(db).resolve_run_id("last") == older
    capsys.readouterr()
    assert main(["show", "last", "--db", str(db)]) == 0
    assert f"run {older}" in capsys.readouterr().out


@pytest.mark.parametrize("edit", [
    "json_set(protocol_json, '$.timing.acquire.samples', json('true'))",
    "json_set(protocol_json, '$.timing.rest_s', json('true'))",
])
def test_resume_refuses_true_where_a_number_was_stored(write_yaml, tmp_path, capsys, edit):
    """A stored protocol is read as a protocol file is: `samples: true` is not one sample."""
    db = tmp_path / "b.sqlite"
    assert main(["sweep", str(write_yaml(SMALL_PROTOCOL)), "--sim", "--db", str(db)]) == 0
    run_id = _cut_last_point(db)
    with sqlite3.connect(db) as con:
        con.execute(f"UPDATE runs SET protocol_json = {edit} WHERE id = ?", (run_id,))
    con.close()
    capsys.readouterr()
    assert main(["sweep", "--resume", run_id, "--db", str(db)]) == 2
    assert "holds true/false" in capsys.readouterr().err
    assert len(Store(db, read_only=True).steps(run_id)) == 3
