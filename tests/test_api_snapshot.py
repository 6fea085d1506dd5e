"""`with lab.snapshot():` makes several API reads see one state of the database (issue item
12): while a writer appends points, `run.points()` and `run.samples()` inside the block agree
every round; nested blocks join the outer one, and the block always ends its read
transaction, also on an exception."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

import rigtool
from rigtool.errors import UsageError
from rigtool.store import StepRecord, Store

ROUNDS = 150
MAX_POINTS = 1500  # the writer stops here, so a round's reads stay short


def _point(store: Store, run_id: str, idx: int, n: int) -> None:
    """Append point `idx` with `n` samples, as a sweep does (one transaction)."""
    t = idx + np.arange(n) / n
    store.add_step(run_id, StepRecord(idx=idx, command=float(idx % 7), command_unit="percent",
                                      depth_m=1.0, repeat=0, direction="up", t_start_s=idx,
                                      t_acquire_s=idx, t_end_s=idx + 1.0, settle_s=0.1,
                                      settled=True, rate_hz=float(n)),
                   {"t_s": t, "thrust_n": np.sin(t), "current_a": np.cos(t)})


@pytest.fixture
def sweep(tmp_path):
    """A store with a run being swept: (database, run id, writer store)."""
    db = tmp_path / "live.sqlite"
    writer = Store(db)
    run_id = writer.create_run(name="live", protocol={}, protocol_path=None, rig={}, plan=[],
                               metadata={}, seed=None, command_unit="percent", tool_version="t")
    for idx in range(3):
        _point(writer, run_id, idx, 50 + 17 * idx)
    yield db, run_id, writer
    writer.close()


def _agree(run: rigtool.api.Run) -> tuple[bool, int]:
    """Read points, then samples; whether they describe the same points, and how many."""
    points = run.points()
    samples = run.samples(columns=["t_s", "thrust_n"])
    same = (np.array_equal(np.unique(samples["step_idx"]), points["step_idx"])
            and int(points["n_samples"].sum()) == samples["t_s"].size)
    return same, len(points["step_idx"])


def test_reads_in_a_snapshot_agree_while_a_writer_appends(sweep):
    db, run_id, writer = sweep
    writer.close()  # the thread opens its own connection
    stop = threading.Event()
    failures: list[BaseException] = []

    def append() -> None:
        try:
            with Store(db) as store:
                for idx in range(3, MAX_POINTS):
                    if stop.is_set():
                        return
                    _point(store, run_id, idx, 40 + (idx * 37) % 300)
                    time.sleep(0.002)
        except BaseException as exc:  # reported by the test, not lost in the thread
            failures.append(exc)

    thread = threading.Thread(target=append)
    thread.start()
    try:
        with rigtool.open(db) as lab:
            run = lab.run(run_id)
            seen, outside = [], 0
            for _ in range(ROUNDS):
                with lab.snapshot():
                    same, n = _agree(run)
                    assert same, f"points and samples disagree inside a snapshot at {n} points"
                    seen.append(n)
                outside += not _agree(run)[0]  # may disagree: two snapshots
    finally:
        stop.set()
        thread.join(timeout=30)
    assert not failures, failures
    assert seen[-1] > seen[0] + 10, "the writer appended too little for the test to mean much"
    print(f"outside a snapshot, {outside} of {ROUNDS} rounds disagreed")


def test_a_write_between_two_reads_is_seen_only_outside_a_snapshot(sweep):
    db, run_id, writer = sweep
    with rigtool.open(db) as lab:
        run = lab.run(run_id)
        with lab.snapshot():
            points = run.points()
            _point(writer, run_id, 3, 80)
            assert len(run.samples()["t_s"]) == points["n_samples"].sum()
            assert lab.runs()[0]["n_steps"] == 3 and lab.run("last").points()["step_idx"].size == 3
        points = run.points()
        _point(writer, run_id, 4, 90)
        assert len(run.samples()["t_s"]) == points["n_samples"].sum() + 90  # two snapshots


def test_nested_blocks_join_and_every_exit_ends_the_snapshot(sweep):
    db, run_id, writer = sweep
    with rigtool.open(db) as lab:
        run = lab.run(run_id)
        with lab.snapshot() as same_lab:
            assert same_lab is lab
            with lab.snapshot():
                before = run.points()["step_idx"].size
            _point(writer, run_id, 3, 60)
            assert run.points()["step_idx"].size == before  # still the outer snapshot
        assert run.points()["step_idx"].size == before + 1 and not lab.store.in_snapshot
        with pytest.raises(ZeroDivisionError), lab.snapshot():
            run.points()
            _ = 1 / 0
        assert not lab.store.in_snapshot
        _point(writer, run_id, 4, 60)
        assert run.points()["step_idx"].size == before + 2
        with lab.snapshot():
            run.events()
            lab.close()  # closing inside the block is harmless


def test_calibrate_inside_a_snapshot_is_refused(sweep):
    db, run_id, _ = sweep
    with rigtool.open(db, write=True) as lab, lab.snapshot():
        with pytest.raises(UsageError, match="outside lab.snapshot"):
            lab.calibrate(run_id)
        assert lab.run(run_id).points()["step_idx"].size == 3
