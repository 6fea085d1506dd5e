"""Calibrate's per-point pass (rigtool.analysis.point_pass): the run is read in blocks of
whole points, the results do not depend on the block size, and memory follows the block,
not the run. Synthetic runs written through the Store."""

import json
import math
import tracemalloc

import numpy as np
import pytest

from rigtool.analysis.blocks import block_means
from rigtool.analysis.calibrate import calibrate
from rigtool.analysis.dataset import SAMPLE_FIELDS, load_run
from rigtool.analysis.point_pass import point_pass
from rigtool.analysis.steady import SettlingCriterion
from rigtool.artefacts.calibration import calibration_document
from rigtool.store import StepRecord, Store

from .test_analysis_calibrate import CREATED, can_samples, sweep, write_run

PER_POINT = 600


@pytest.fixture(scope="module")
def can_run(tmp_path_factory):
    store = Store(tmp_path_factory.mktemp("perpoint") / "runs.sqlite")
    plan = sweep(np.arange(-100.0, 100.1, 10.0), depths=(0.5, 1.0), updown=True)
    return store, write_run(store, can_samples, "percent", plan, n_samples=PER_POINT, seed=3)


def _calibrate(store, run_id, batch):
    run = load_run(store, run_id)
    run.source.batch = batch
    return calibrate(run)


def _numbers(doc, where=""):
    """Every leaf of a JSON document by its path."""
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _numbers(v, f"{where}.{k}")
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _numbers(v, f"{where}[{i}]")
    else:
        yield where, doc


def test_blocks_are_whole_points_covering_the_run_once(can_run):
    store, run_id = can_run
    run = load_run(store, run_id)
    run.source.batch = 1500
    whole = store.samples(run_id, ("step_id", *SAMPLE_FIELDS))
    blocks = list(run.source.blocks())
    rows = np.concatenate([b.rows for b in blocks])
    assert np.array_equal(rows, np.arange(len(run.steps)))
    for b in blocks:  # whole points, at most the batch (or one point longer than it)
        assert b.samples.t_s.size <= max(1500, PER_POINT)
        assert np.all(np.diff(b.samples.offsets) == PER_POINT)
    for name in SAMPLE_FIELDS:
        got = np.concatenate([getattr(b.samples, name) for b in blocks])
        assert np.array_equal(got, whole[name], equal_nan=True), name


def test_results_do_not_depend_on_the_block_size(can_run):
    store, run_id = can_run
    docs = [calibration_document(_calibrate(store, run_id, batch), CREATED)
            for batch in (250, 4000, 10**9)]  # pieces of every point, several points, the whole run
    leaves = [dict(_numbers(json.loads(json.dumps(d, default=str)))) for d in docs]
    assert leaves[0].keys() == leaves[1].keys() == leaves[2].keys()
    fits = docs[0]["sections"][0]["fits"] if "sections" in docs[0] else None
    assert fits is None or "sigma_i_sample" in json.dumps(fits)
    for path, ref in leaves[2].items():
        for other in leaves[:2]:
            value = other[path]
            if isinstance(ref, float) and math.isfinite(ref):
                assert value == pytest.approx(ref, rel=1e-12, abs=1e-300), path
            else:
                assert value == ref, path


def test_sample_spreads_are_computed(can_run):
    store, run_id = can_run
    cal = _calibrate(store, run_id, 2000)
    for sec in cal.sections:
        for name in ("sigma_n_sample", "sigma_i_sample"):
            c = sec.fits[name]
            assert c.n > 0 and 0.1 < c.value < 1.0, (name, c)  # the twin's noise: 0.2 N + hum


def _peak_bytes(store, run_id, batch):
    """Peak traced allocation of calibrating `run_id` with blocks of `batch` samples."""
    tracemalloc.start()
    try:
        _calibrate(store, run_id, batch)
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_memory_follows_the_block_not_the_run(tmp_path):
    store = Store(tmp_path / "long-points.sqlite")
    per_point = 5000
    plan = sweep(np.arange(-100.0, 100.1, 10.0), depths=(0.5, 1.0))
    run_id = write_run(store, can_samples, "percent", plan, n_samples=per_point, seed=4)
    _calibrate(store, run_id, per_point)  # warm: imports and caches outside the count
    by_point = _peak_bytes(store, run_id, per_point)
    whole = _peak_bytes(store, run_id, 10**9)
    # One point a block holds a 42nd of the samples; what is left is per point, or a
    # constant (the at most 200 000 values a channel's printed step is looked for in).
    assert by_point < 0.35 * whole, (by_point, whole)


def _long_point_run(store):
    """Points of 900-1500 samples with voltage and torque recorded: held commands, ramps
    (the command moves within the point) and one with a NaN gap in its current."""
    rng = np.random.default_rng(11)
    rig = {"thrust": {"channel": "fx", "sign": -1}}
    run_id = store.create_run(name="long", protocol={"command": {"unit": "percent"}},
                              protocol_path=None, rig=rig, plan=[], metadata={}, seed=11,
                              command_unit="percent", tool_version="test")
    t = 0.0
    for i, cmd in enumerate(np.linspace(-80, 80, 9)):
        n_samples = 900 + 75 * i
        tt = np.arange(n_samples) / 1000.0
        moving = i % 3 == 1
        command = cmd + (np.linspace(0, 10, n_samples) if moving else 0.0 * tt)
        speed = 18 * command * (1 - np.exp(-(tt + 0.01) / 0.05)) + rng.normal(0, 2, n_samples)
        thrust = 2e-5 * np.abs(speed) * speed + rng.normal(0, 0.2, n_samples)
        current = 1e-9 * np.abs(speed) ** 3 + 0.3 + rng.normal(0, 0.05, n_samples)
        if i == 4:
            current[100:400] = np.nan
        samples = {"t_s": t + tt, "fx": -thrust, "tx": 0.01 * thrust + rng.normal(0, 1e-3, n_samples),
                   "thrust_n": thrust, "speed_rpm": speed, "current_a": current,
                   "voltage_v": 48 + rng.normal(0, 0.1, n_samples), "command": command}
        step = StepRecord(i, float(cmd), "percent", None, 0, "up", t, t, t + tt[-1], 0.0,
                          True, 1000.0)
        store.add_step(run_id, step, samples)
        t += tt[-1] + 0.5
    store.finish_run(run_id, "completed")
    return run_id


def _same(a, b, where):
    assert np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True), where


def test_a_point_longer_than_a_block_is_streamed_in_pieces_bit_for_bit(tmp_path):
    """A point longer than the block comes in pieces and gets its own passes: its window,
    statistics (held, ramp, NaN gaps, power, torque) and block means are those of the whole
    point to the last bit, whatever the piece size."""
    store = Store(tmp_path / "long.sqlite")
    run_id = _long_point_run(store)
    results = []
    for batch in (10**9, 1000, 333):
        run = load_run(store, run_id)
        run.source.batch = batch
        assert run.source.has_torque
        pieces = [b for b in run.source.blocks() if b.piece]
        assert bool(pieces) == (batch < 10**9)
        assert all(b.samples.t_s.size <= batch for b in pieces)
        windows, table = point_pass(run, SettlingCriterion())
        results.append((windows, table, block_means(run, 0.05)))
    ref_w, ref_t, ref_b = results[0]
    assert np.isfinite(ref_w.speed_sq_rate).sum() == 3  # the ramps are seen as moving
    assert np.isfinite(ref_t.torque.mean).all() and np.isfinite(ref_t.power.mean).all()
    for windows, table, blocks in results[1:]:
        for name in ("first", "window_start_s", "t_mid_s", "n_window", "unsteady",
                     "speed_sq_rate"):
            _same(getattr(windows, name), getattr(ref_w, name), name)
        for name, stats in windows.channels.items():
            for k in ("mean", "std", "se", "min", "max"):
                _same(getattr(stats, k), getattr(ref_w.channels[name], k), (name, k))
        _same(table.n_samples, ref_t.n_samples, "n_samples")
        for k in ("t_s", "t0_s", "t1_s", "thrust_n", "speed_rpm", "current_a", "point"):
            _same(getattr(blocks, k), getattr(ref_b, k), k)


def _dwell_run(store, n):
    """A short sweep, then a dwell of `n` samples at 60 %."""
    plan = sweep(np.arange(-100.0, 100.1, 20.0))
    run_id = write_run(store, can_samples, "percent", plan, n_samples=400, seed=6)
    rng = np.random.default_rng(6)
    t0 = 1000.0
    tt = np.arange(n) / 1000.0
    speed = 1080 + rng.normal(0, 2, n)
    samples = {"t_s": t0 + tt, "thrust_n": 2e-5 * speed * speed + rng.normal(0, 0.2, n),
               "speed_rpm": speed, "current_a": 1.2e-9 * speed**3 + 0.3 + rng.normal(0, 0.05, n),
               "command": np.full(n, 60.0)}
    store.add_step(run_id, StepRecord(len(plan), 60.0, "percent", None, 0, "up", t0, t0,
                                      t0 + tt[-1], 0.0, True, 1000.0), samples)
    return run_id


def test_memory_of_one_long_point_does_not_grow_with_it(tmp_path):
    """Calibrated in pieces of 20 000 samples, a run whose dwell is 3 times longer peaks at
    about the same memory (both past the constants: a block of a point for the thrust
    axis, 200 000 values a channel for the printed step); the shorter dwell read whole
    needs more than both."""
    peaks = {}
    for n in (300_000, 900_000):
        store = Store(tmp_path / f"dwell{n}.sqlite")
        run_id = _dwell_run(store, n)
        if n == 300_000:
            _calibrate(store, run_id, 20_000)  # warm: imports and caches outside the count
            peaks["whole"] = _peak_bytes(store, run_id, 10**9)
        peaks[n] = _peak_bytes(store, run_id, 20_000)
    assert peaks[900_000] < 1.1 * peaks[300_000], peaks
    assert peaks["whole"] > 2 * peaks[900_000], peaks
