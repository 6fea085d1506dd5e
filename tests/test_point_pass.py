"""Calibrate's per-point pass (rigtool.analysis.point_pass): the run is read in blocks of
whole points, the results do not depend on the block size, and memory follows the block,
not the run. Synthetic runs written through the Store."""

import json
import math
import tracemalloc

import numpy as np
import pytest

from rigtool.analysis.calibrate import calibrate
from rigtool.analysis.dataset import SAMPLE_FIELDS, load_run
from rigtool.artefacts.calibration import calibration_document
from rigtool.store import Store

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
