"""The run store: schema and migrations, run ids, run lookup, dead-run detection."""

from __future__ import annotations

import sqlite3

import numpy as np
import pytest

from rigtool.errors import StoreError, UsageError
from rigtool.ids import new_run_id
from rigtool.store import SCHEMA_VERSION, StepRecord, Store

from .hostile import run_cli


def _run(store: Store) -> str:
    return store.create_run(name="r", protocol={"a": 1}, protocol_path="p.yaml", rig={"b": 2},
                            plan=[{"idx": 0}], metadata={"operator": "x"}, seed=5,
                            command_unit="percent", tool_version="t")


def _step(idx: int) -> StepRecord:
    return StepRecord(idx=idx, command=10.0 * idx, command_unit="percent", depth_m=1.0, repeat=0,
                      direction="up", t_start_s=0, t_acquire_s=1, t_end_s=2, settle_s=1,
                      settled=True, rate_hz=100)


def test_new_store_has_current_schema_and_wal(db_path):
    store = Store(db_path)
    assert store.version == SCHEMA_VERSION
    assert store.conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    tables = {r[0] for r in store.conn.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    assert {"runs", "steps", "sample_blocks", "events", "calibrations"} <= tables
    assert "samples" not in tables  # rows became column blocks in v8


def test_reopening_does_not_migrate_again(db_path):
    Store(db_path).close()
    store = Store(db_path)
    assert store.version == SCHEMA_VERSION


def test_newer_schema_is_refused(db_path):
    Store(db_path).close()
    conn = sqlite3.connect(db_path)
    conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION + 1}")
    conn.close()
    with pytest.raises(StoreError, match="upgrade rigtool"):
        Store(db_path)


def test_newer_schema_is_a_usage_error_for_every_command(db_path, tmp_path):
    """Exit 2 from the commands that write (calibrate, sweep) and those that only read, as
    from merge: the database is not this rigtool's to use."""
    Store(db_path).close()
    conn = sqlite3.connect(db_path)
    conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION + 1}")
    conn.close()
    for args in (["calibrate", "last"], ["report", "last"], ["runs"], ["merge", str(db_path)]):
        target = ["--db", str(db_path)] if args[0] != "merge" else ["-o", str(tmp_path / "o.sqlite")]
        proc = run_cli(*args, *target, cwd=tmp_path)
        assert proc.returncode == 2, (args, proc.stderr)
        assert "upgrade rigtool" in proc.stderr or "schema version" in proc.stderr, proc.stderr
        assert "Traceback" not in proc.stderr


def test_run_ids_sort_by_time_and_are_unique():
    ids = [new_run_id() for _ in range(200)]
    assert len(set(ids)) == 200
    assert ids == sorted(ids, key=lambda i: i.split("-")[0])


def test_step_and_samples_roundtrip_with_missing_channels(db_path):
    store = Store(db_path)
    run_id = _run(store)
    n = 50
    samples = {"t_s": np.arange(n) * 0.01, "fx": np.ones(n), "thrust_n": np.linspace(0, 1, n),
               "speed_rpm": None, "current_a": np.full(n, 2.0), "command": np.full(n, 10.0)}
    store.add_step(run_id, _step(1), samples)
    (step,) = store.steps(run_id)
    assert step["n"] == n and step["speed_all_mean_rpm"] is None
    assert step["thrust_all_mean_n"] == pytest.approx(0.5)
    back = store.samples(run_id)
    assert np.allclose(back["thrust_n"], samples["thrust_n"])
    assert np.isnan(back["speed_rpm"]).all() and np.isnan(back["fy"]).all()
    run = store.run(run_id)
    assert run["protocol"] == {"a": 1} and run["metadata"] == {"operator": "x"} and run["seed"] == 5


def test_failed_step_insert_leaves_nothing(db_path):
    store = Store(db_path)
    run_id = _run(store)
    store.add_step(run_id, _step(0), {"t_s": np.zeros(3)})
    with pytest.raises(sqlite3.IntegrityError):  # same idx twice violates UNIQUE(run_id, idx)
        store.add_step(run_id, _step(0), {"t_s": np.zeros(3)})
    assert store.conn.execute("SELECT sum(n) FROM sample_blocks").fetchone()[0] == 3


def test_resolve_last_prefix_and_errors(db_path):
    store = Store(db_path)
    with pytest.raises(UsageError, match="no runs"):
        store.resolve_run_id("last")
    first = _run(store)
    second = _run(store)
    assert store.resolve_run_id("last") == second  # even when both ids share a millisecond
    assert store.resolve_run_id(first) == first
    with pytest.raises(UsageError, match="no run"):
        store.resolve_run_id("19990101")
    with pytest.raises(UsageError, match="ambiguous"):
        store.resolve_run_id(first[:4])


def test_last_is_the_run_most_recently_started_or_resumed(db_path):
    store = Store(db_path)
    older = _run(store)
    store.finish_run(older, "aborted", "test")
    newer = _run(store)
    assert store.resolve_run_id("last") == newer
    store.reopen_run(older)
    assert store.resolve_run_id("last") == older


def test_actuator_is_stored_with_the_run(db_path):
    store = Store(db_path)
    actuator = {"command_unit": "pulse_us", "neutral": 1490.0, "command_min": 1100.0,
                "command_max": 1900.0, "feedback": []}
    run_id = store.create_run(name="r", protocol={}, protocol_path=None, rig={}, plan=[],
                              metadata={}, seed=None, command_unit="pulse_us", tool_version="t",
                              actuator=actuator)
    assert store.run(run_id)["actuator"] == actuator and store.run(_run(store))["actuator"] is None


def test_run_of_dead_process_reads_as_interrupted(db_path):
    store = Store(db_path)
    run_id = _run(store)
    store.conn.execute("UPDATE runs SET pid = 2147483646 WHERE id = ?", (run_id,))
    store.close()
    assert Store(db_path).run(run_id)["status"] == "interrupted"


def test_missing_database_for_reading_is_usage_error(tmp_path):
    with pytest.raises(UsageError, match="no run database"):
        Store(tmp_path / "none.sqlite", create=False)


def test_migration_from_v1_keeps_data_and_adds_seq(db_path):
    from rigtool.store import SCHEMA_V1

    conn = sqlite3.connect(db_path)
    conn.executescript(SCHEMA_V1)
    conn.execute("PRAGMA user_version = 1")
    conn.execute("INSERT INTO runs VALUES ('r1','old','completed','2026-01-01',NULL,'0.0','h',1,NULL,"
                 "NULL,'{}','{}','[]','{}',1,'percent',NULL)")
    conn.execute("INSERT INTO steps (run_id, idx, command, command_unit, repeat, direction, t_start_s,"
                 " t_acquire_s, t_end_s, settle_s, settled, rate_hz, status, n) "
                 "VALUES ('r1',0,5,'percent',0,'up',0,0,1,0,1,10,'ok',1)")
    conn.execute("INSERT INTO samples (step_id, t_s, thrust_n) VALUES (1, 0.5, 2.5)")
    conn.commit()
    conn.close()
    store = Store(db_path)
    assert store.version == SCHEMA_VERSION >= 5
    assert store.steps("r1")[0]["counters_json"] is None
    assert store.transport_counters("r1") == {"totals": {}, "problem_points": []}
    back = store.samples("r1", ["t_s", "thrust_n", "seq"])
    assert back["thrust_n"][0] == 2.5 and np.isnan(back["seq"][0])
    run = store.run("r1")
    assert run["actuator"] is None and run["started_utc"] == run["created_utc"] == "2026-01-01"
    new = _run(store)  # a run started after the migration is `last`
    assert store.resolve_run_id("last") == new


def test_migration_to_blocks_keeps_every_sample_in_order(db_path, monkeypatch):
    """v7 -> v8: rows become column blocks per point, chunked, with NULLs as NaN and absent
    channels as NULL blocks; the rows table is gone."""
    import rigtool.store.schema
    from rigtool.store import MIGRATIONS

    monkeypatch.setattr(rigtool.store.schema, "SAMPLES_PER_CHUNK", 4)
    conn = sqlite3.connect(db_path, isolation_level=None)
    for migrate in MIGRATIONS[:7]:
        migrate(conn)
    conn.execute("PRAGMA user_version = 7")
    conn.execute("INSERT INTO runs (id, name, status, created_utc, tool_version, host, pid, "
                 "protocol_json, rig_json, plan_json, metadata_json, n_planned, command_unit) "
                 "VALUES ('r1','old','completed','2026-01-01','0.0','h',1,'{}','{}','[]','{}',2,"
                 "'percent')")
    sizes = {0: 9, 1: 3}
    rng = np.random.default_rng(3)
    rows = []
    for idx, n in sizes.items():
        step_id = conn.execute(
            "INSERT INTO steps (run_id, idx, command, command_unit, repeat, direction, "
            "t_start_s, t_acquire_s, t_end_s, settle_s, settled, rate_hz, status, n) "
            "VALUES ('r1',?,5,'percent',0,'up',0,0,1,0,1,10,'ok',?)", (idx, n)).lastrowid
        for k in range(n):
            row = (step_id, idx * 100 + k, float(rng.normal()), None if k % 3 == 0 else k * 2.0,
                   idx * 1000 + k)
            rows.append(row)
    conn.executemany("INSERT INTO samples (step_id, t_s, thrust_n, speed_rpm, seq) "
                     "VALUES (?, ?, ?, ?, ?)", rows)
    conn.close()
    store = Store(db_path)
    tables = {r[0] for r in store.conn.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    assert "samples" not in tables and store.version == SCHEMA_VERSION
    assert [tuple(r) for r in store.conn.execute(
        "SELECT step_id, chunk, n, fx IS NULL FROM sample_blocks ORDER BY id")] == [
        (1, 0, 4, 1), (1, 1, 4, 1), (1, 2, 1, 1), (2, 0, 3, 1)]
    back = store.samples("r1", ["t_s", "thrust_n", "speed_rpm", "fx"])
    np.testing.assert_array_equal(back["t_s"], [r[1] for r in rows])
    np.testing.assert_array_equal(back["thrust_n"], [r[2] for r in rows])
    np.testing.assert_array_equal(back["speed_rpm"], [np.nan if r[3] is None else r[3] for r in rows])
    assert np.isnan(back["fx"]).all()
    arrays = store.sample_arrays("r1", ["seq"])
    assert arrays["seq"].tolist() == [r[4] for r in rows]
    assert arrays["step_idx"].tolist() == [0] * 9 + [1] * 3


def test_transport_counters_are_stored_with_each_point_and_summed(db_path):
    store = Store(db_path)
    run_id = _run(store)
    samples = {"t_s": np.arange(3.0), "thrust_n": np.ones(3)}
    per_point = [
        {"actuator": {"frames": 50, "garbage": 0}, "sensor": {"records": 200, "lost_packets": 0}},
        {"actuator": {"frames": 48, "garbage": 2}, "sensor": {"records": 190, "lost_packets": 10}},
        None,  # simulated devices keep no counters
    ]
    for idx, counters in enumerate(per_point):
        step = _step(idx)
        step.counters = counters
        store.add_step(run_id, step, samples)
    assert [s["counters_json"] is None for s in store.steps(run_id)] == [False, False, True]
    assert store.transport_counters(run_id) == {
        "totals": {"actuator": {"frames": 98, "garbage": 2},
                   "sensor": {"records": 390, "lost_packets": 10}},
        "problem_points": [1]}


def test_sequence_numbers_are_stored(db_path, write_yaml):
    from rigtool.cli import main

    from .conftest import SMALL_PROTOCOL

    assert main(["sweep", str(write_yaml(SMALL_PROTOCOL)), "--sim", "--db", str(db_path)]) == 0
    store = Store(db_path)
    seq = store.samples(store.resolve_run_id("last"), ["seq"])["seq"]
    assert np.all(np.diff(seq) > 0)  # the sensor's own counter, increasing over the run


def test_concurrent_first_open_migrates_once(db_path):
    import threading

    errors = []

    def open_store():
        try:
            Store(db_path).close()
        except Exception as exc:  # noqa: BLE001 - collected for the assertion
            errors.append(exc)

    for _ in range(5):
        db_path.unlink(missing_ok=True)
        threads = [threading.Thread(target=open_store) for _ in range(4)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert not errors, errors
        assert Store(db_path).version == SCHEMA_VERSION
