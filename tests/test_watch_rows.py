"""The watch page reads a run's points and counters incrementally (Store.points_since and
transport_counters after a row): each read equals a full read, and a read after one more
point fetches that point only."""

from __future__ import annotations

import json

import numpy as np

from rigtool.store import StepRecord, Store
from rigtool.watch.rows import RunRows


def _run(store: Store) -> str:
    return store.create_run(name="r", protocol={}, protocol_path=None, rig={}, plan=[],
                            metadata={}, seed=1, command_unit="percent", tool_version="t")


def _add(store: Store, run_id: str, idx: int, rng: np.random.Generator) -> None:
    counters = {"sensor": {"frames": int(rng.integers(1, 9)), "garbage": int(idx % 3 == 0)}}
    if idx % 4 == 1:
        counters["actuator"] = {"sent": 2, "timeouts": 1}
    step = StepRecord(idx=idx, command=float(idx), command_unit="percent",
                      depth_m=None if idx % 2 else 1.5, repeat=0,
                      direction="up" if idx % 2 else "down", t_start_s=idx, t_acquire_s=idx + 0.5,
                      t_end_s=idx + 1.0, settle_s=0.5, settled=bool(idx % 5), rate_hz=100.0,
                      counters=counters if idx % 6 else None, voltage_v=12.0 if idx > 3 else None)
    n = int(rng.integers(1, 30))
    store.add_step(run_id, step, {"t_s": np.arange(n) / 100.0, "thrust_n": rng.normal(size=n),
                                  "speed_rpm": rng.normal(100, 5, size=n)})


def _same(rows: RunRows, store: Store, run_id: str) -> None:
    """One incremental read, in one snapshot, equals a full read of the same snapshot."""
    with store.snapshot():
        points = rows.points(store, run_id)
        counters = rows.counters(store, run_id)
        full_points, full_counters = store.points(run_id), store.transport_counters(run_id)
    assert list(points) == list(full_points)
    for name, values in full_points.items():
        assert points[name].dtype == values.dtype, name
        np.testing.assert_array_equal(points[name], values)
    assert counters == full_counters
    assert [list(c) for c in counters["totals"].values()] == [
        list(c) for c in full_counters["totals"].values()]  # same order as a full read


def test_incremental_reads_equal_full_reads(tmp_path):
    rng = np.random.default_rng(7)
    store = Store(tmp_path / "runs.sqlite")
    run_id, other = _run(store), _run(store)
    rows = RunRows()
    _same(rows, store, run_id)  # no points yet
    for idx in range(12):
        _add(store, run_id, idx, rng)
        _same(rows, store, run_id)
        _same(rows, store, run_id)  # nothing new
    _add(store, run_id, 20, rng)
    _same(rows, store, run_id)
    _add(store, run_id, 15, rng)  # before a kept point: read in full again
    _same(rows, store, run_id)
    _add(store, other, 0, rng)
    _same(rows, store, other)  # another run
    _add(store, run_id, 21, rng)
    _same(rows, store, run_id)


def test_points_since_fetches_only_the_new_rows(tmp_path):
    rng = np.random.default_rng(3)
    store = Store(tmp_path / "runs.sqlite")
    run_id = _run(store)
    for idx in range(5):
        _add(store, run_id, idx, rng)
    points, last = store.points_since(run_id, None)
    assert points["step_idx"].tolist() == [0, 1, 2, 3, 4] and last is not None
    again, same = store.points_since(run_id, last)
    assert again["step_idx"].size == 0 and same == last
    _add(store, run_id, 5, rng)
    new, newest = store.points_since(run_id, last)
    assert new["step_idx"].tolist() == [5] and newest > last
    assert store.transport_counters(run_id, newest) == {"totals": {}, "problem_points": []}
    assert store.transport_counters(run_id, last) == {
        "totals": {"sensor": {"frames": _frames(store, run_id, 5), "garbage": 0},
                   "actuator": {"sent": 2, "timeouts": 1}},
        "problem_points": [5]}


def _frames(store: Store, run_id: str, idx: int) -> int:
    """The `frames` counter stored with point `idx`."""
    (step,) = [s for s in store.steps(run_id) if s["idx"] == idx]
    return json.loads(step["counters_json"])["sensor"]["frames"]
