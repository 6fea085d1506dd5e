"""Acquisition memory is bounded by the block size, not by the samples per point: a long
point spills to disk and streams into the store, with the same statistics and rows."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

import rigtool.engine
import rigtool.spool
from rigtool.engine import Engine
from rigtool.spool import SampleSpool
from rigtool.store import SAMPLE_COLUMNS, STAT_FIELDS, Store
from rigtool.sweep import open_checked, resolve

from .conftest import SMALL_PROTOCOL


def _blocks(rng, sizes):
    for n in sizes:
        block = {c: rng.normal(3.0, 2.0, n) for c in SAMPLE_COLUMNS[1:]}
        block["speed_rpm"][::7] = np.nan  # missing feedback is left out of the statistics
        block["current_a"] = np.full(n, np.nan)
        yield block


@pytest.mark.parametrize("limit", [10**9, 1000])
def test_spilled_and_in_memory_spools_agree_with_numpy(tmp_path, monkeypatch, limit):
    monkeypatch.setattr(rigtool.spool, "IN_MEMORY_SAMPLES", limit)
    monkeypatch.setattr(rigtool.spool, "SAMPLES_PER_CHUNK", 333)
    blocks = list(_blocks(np.random.default_rng(1), [400, 1, 900, 250]))
    spool = SampleSpool(SAMPLE_COLUMNS[1:], STAT_FIELDS, spill_dir=tmp_path)
    for block in blocks:
        spool.add(block)
    assert spool.spilled == (limit < 1551) and spool.n == 1551
    chunks = list(spool.column_chunks())
    assert [len(ch["t_s"]) for ch in chunks] == [333] * 4 + [219]
    for c in SAMPLE_COLUMNS[1:]:
        np.testing.assert_array_equal(np.concatenate([ch[c] for ch in chunks]),
                                      np.concatenate([b[c] for b in blocks]))
    for name in STAT_FIELDS:
        v = np.concatenate([b[name] for b in blocks])
        v = v[np.isfinite(v)]
        expected = (v.mean(), v.std(ddof=1), v.min(), v.max()) if v.size else None
        assert spool.stats(name) == (pytest.approx(expected, rel=1e-12) if expected else None)
    assert spool.mean("thrust_n") == pytest.approx(np.concatenate([b["thrust_n"] for b in blocks]).mean())
    spool.close()


def _long_point_peak(tmp_path, samples: int) -> tuple[int, dict]:
    text = (SMALL_PROTOCOL.replace("values: [-50, 0, 50, 100]", "values: [50]")
            .replace("acquire: {samples: 200, rate_hz: 500}",
                     f"acquire: {{samples: {samples}, rate_hz: 100000}}")
            .replace("settle: {seconds: 0.5}", "settle: {seconds: 0}").replace("rest_s: 0.2", "rest_s: 0"))
    path = tmp_path / f"p{samples}.yaml"
    path.write_text(text)
    setup = resolve(path, sim=True)
    rigset = open_checked(setup)
    store = Store(tmp_path / f"r{samples}.sqlite")
    run_id = store.create_run(name="t", protocol={}, protocol_path=None, rig={}, plan=[],
                              metadata={}, seed=1, command_unit="percent", tool_version="test")
    tracemalloc.start()
    try:
        outcome = Engine(setup.protocol, setup.plan, rigset, store, run_id).run()
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
        rigset.close()
    assert outcome.status == "completed"
    (step,) = store.steps(run_id)
    thrust = store.samples(run_id, ["thrust_n"])["thrust_n"]
    assert step["n"] == samples == thrust.size
    assert step["thrust_all_mean_n"] == pytest.approx(thrust.mean(), rel=1e-9)
    assert step["thrust_all_std_n"] == pytest.approx(thrust.std(ddof=1), rel=1e-6)
    store.close()
    return peak, step


def test_acquisition_memory_does_not_grow_with_the_point(tmp_path, monkeypatch):
    monkeypatch.setattr(rigtool.spool, "IN_MEMORY_SAMPLES", 10_000, raising=False)
    monkeypatch.setattr(rigtool.engine, "FOLD_SAMPLES", 10_000, raising=False)
    short, _ = _long_point_peak(tmp_path, 40_000)
    long, _ = _long_point_peak(tmp_path, 200_000)
    # five times the samples: the old engine held every block, their concatenation and the
    # store's row list (about 5x the peak); the spool holds one block at a time
    assert long < 1.5 * short, (short, long)
