"""Hostile storage: unopenable paths, a full disk mid-run, a locked DB, two sweeps on one DB."""

from __future__ import annotations

import sqlite3
import subprocess
import sys

import pytest

from rigtool.cli import main
from rigtool.engine import Engine
from rigtool.errors import StoreError
from rigtool.store import Store

from .conftest import SMALL_PROTOCOL
from .test_engine import FaultySensor, _setup


def test_db_path_under_a_file_is_a_clear_error(tmp_path, write_yaml, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    status = main(["sweep", str(write_yaml(SMALL_PROTOCOL)), "--sim", "--db", str(blocker / "runs.sqlite")])
    err = capsys.readouterr().err
    assert status == 1 and "cannot open run database" in err and "Traceback" not in err


def test_not_a_database_is_a_clear_error(tmp_path):
    bad = tmp_path / "junk.sqlite"
    bad.write_bytes(b"this is not sqlite" * 100)
    with pytest.raises(StoreError, match="junk.sqlite"):
        Store(bad)


def test_disk_full_mid_run_keeps_committed_points_and_neutral(write_yaml, db_path):
    setup, rigset = _setup(write_yaml)
    store = Store(db_path)
    run_id = store.create_run(name="t", protocol={}, protocol_path=None, rig={}, plan=[],
                              metadata={}, seed=1, command_unit="percent", tool_version="test")

    def fill_disk():
        pages = store.conn.execute("PRAGMA page_count").fetchone()[0]
        store.conn.execute(f"PRAGMA max_page_count = {pages + 1}")

    rigset.sensor = FaultySensor(rigset.sensor, at=20, action=fill_disk)
    with pytest.raises(StoreError, match="full"):
        Engine(setup.protocol, setup.plan, rigset, store, run_id).run()
    assert rigset.actuator.sent[-1] == 0.0
    store.close()
    store = Store(db_path)
    assert store.conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    steps = store.steps(run_id)
    assert 1 <= len(steps) < 4
    for s in steps:
        assert s["n"] == len(store.step_samples(s["id"], ["t_s", "thrust_n"])["thrust_n"]) == 200


def test_locked_database_is_a_clear_error(db_path):
    Store(db_path).close()
    other = sqlite3.connect(db_path, isolation_level=None)
    other.execute("BEGIN IMMEDIATE")
    try:
        store = Store(db_path, timeout_s=0.2)
        with pytest.raises(StoreError, match="locked"):
            store.add_event("nope", "warning", {})
    finally:
        other.execute("ROLLBACK")
        other.close()


@pytest.mark.slow
def test_two_sweeps_on_one_database_both_complete(write_yaml, db_path):
    path = write_yaml(SMALL_PROTOCOL.replace("rest_s: 0.2", "rest_s: 30"))
    cmd = [sys.executable, "-m", "rigtool.cli", "sweep", str(path), "--sim", "--db", str(db_path)]
    procs = [subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(2)]
    for p in procs:
        _, err = p.communicate(timeout=60)
        assert p.returncode == 0, err
    store = Store(db_path)
    runs = store.runs()
    assert len(runs) == 2 and {r["status"] for r in runs} == {"completed"}
    assert all(len(store.steps(r["id"])) == 4 for r in runs)


def test_a_transaction_a_signal_left_open_does_not_block_the_runs_end(write_yaml, db_path):
    """A SIGTERM between BEGIN and the block that writes a point left the transaction open;
    the run's end then failed ('cannot start a transaction within a transaction') and the run
    stayed `running`. The leftover is rolled back: its half-written point is not kept."""
    assert main(["sweep", str(write_yaml(SMALL_PROTOCOL)), "--sim", "--db", str(db_path)]) == 0
    store = Store(db_path)
    run_id = store.resolve_run_id("last")
    name = store.run(run_id)["name"]
    store.conn.execute("BEGIN IMMEDIATE")  # as the interrupted write left it
    store.conn.execute("UPDATE runs SET name = 'half-written' WHERE id = ?", (run_id,))
    store.finish_run(run_id, "aborted", "stopped by SIGTERM")
    store.close()
    with Store(db_path, read_only=True) as again:
        run = again.run(run_id)
        assert (run["status"], run["name"]) == ("aborted", name)
