"""Quasi-cavitation pipeline on small twin runs (reduced protocols: few points, short dwell)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from rigtool.analysis.cavitation import calibrate_cavitation, evaluate_on_run
from rigtool.analysis.cavitation_runs import find_base_run, is_shallow
from rigtool.analysis.gp import GpParams, sklearn_predict
from rigtool.analysis.results import CavitationParams
from rigtool.artefacts.cavitation import (
    TRAIN_CSV,
    TRAIN_PARQUET,
    write_cavitation_artefacts,
)
from rigtool.cli import main
from rigtool.models import CURRENT_FAULT, OUT_OF_DOMAIN, load_model
from rigtool.report import render_report
from rigtool.store import Store

BASE = """rigtool_protocol: 1
name: mini-baseline
simulator: {profile: can-bldc, seed: 7}
metadata: {thruster_id: bldc-350w}
command: {unit: percent, range: {start: -100, stop: 100, step: 10}, order: up}
depth: {unit: m, values: [1.0], mode: preset}
timing: {settle: {seconds: 1.0}, acquire: {samples: 600, rate_hz: 500}, rest_s: 0.2,
         tare: per_depth, tare_s: 0.5}
limits: {max_thrust_n: 90, max_current_a: 12, max_speed_rpm: 2000, slew_per_s: 200}
"""
CAV = """rigtool_protocol: 1
name: mini-cavitation
simulator: {profile: can-bldc, seed: 4}
metadata: {thruster_id: bldc-350w}
command: {unit: percent, values: [69, 90], order: up}
depth: {unit: cm, values: [20, 40], mode: manual}
timing: {settle: {seconds: 1.0}, acquire: {seconds: 12, rate_hz: 250}, rest_s: 1.0,
         tare: per_depth}
limits: {max_thrust_n: 90, max_current_a: 12, max_speed_rpm: 2000, slew_per_s: 200}
"""
PARAMS = CavitationParams(budget=150, gp=GpParams(hyper_n=250, n_restarts=0))


def _sweep(tmp: Path, text: str, name: str, seed: int) -> str:
    path = tmp / name
    path.write_text(text)
    assert main(["sweep", str(path), "--sim", "--seed", str(seed), "--db", str(tmp / "db.sqlite")]) == 0
    return Store(tmp / "db.sqlite").runs(limit=1)[0]["id"]


@pytest.fixture(scope="module")
def twin(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("cav")
    base = _sweep(tmp, BASE, "base.yaml", 7)
    train = _sweep(tmp, CAV, "cav.yaml", 31)
    test = _sweep(tmp, CAV, "cav.yaml", 32)
    store = Store(tmp / "db.sqlite")
    res = calibrate_cavitation(store, train, None, PARAMS)
    return tmp, store, base, train, test, res


def test_base_run_found_and_shallow_flag(twin):
    _, store, base, train, _, res = twin
    assert find_base_run(store, train) == base == res.base_run_id
    assert is_shallow(store, train) and not is_shallow(store, base)


def test_events_stored_once_and_match_truth(twin):
    _, store, _, train, _, res = twin
    for _ in range(2):  # a rerun replaces the events instead of adding to them
        store.replace_events(train, "ventilation", res.events)
    stored = store.events(train, "ventilation")
    assert len(stored) == len(res.events) > 0
    d = stored[0]["detail"]
    assert {"t_start_s", "t_end_s", "depth_m", "command", "mean_drop_frac"} <= set(d)
    m = res.evaluation.matching
    assert m is not None and m.recall >= 0.9 and m.false_rate <= 0.1


def test_betm_beats_single_sources_on_deep_points(twin):
    speed, current, fused = twin[-1].deep_errors_samples
    assert fused.rms_n < 0.95 * min(speed.rms_n, current.rms_n)
    assert fused.p95_abs_n < 0.95 * min(speed.p95_abs_n, current.p95_abs_n)
    assert fused.within_1n > max(speed.within_1n, current.within_1n)
    speed, current, fused = twin[-1].deep_errors  # block means: force noise averaged out
    assert fused.rms_n < min(speed.rms_n, current.rms_n)
    assert fused.max_abs_n < min(speed.max_abs_n, current.max_abs_n)


def test_training_set_bounded_and_weighted(twin):
    res = twin[-1]
    t = res.training
    assert 0 < len(t) <= PARAMS.budget < res.n_blocks_total
    assert np.all((t.w > 0) & (t.w <= 1)) and t.ventilated.any() and (~t.ventilated).any()


def test_artefacts_and_model_reload(twin):
    tmp, store, _, train, _, res = twin
    paths = write_cavitation_artefacts(res, tmp / "out", created_utc="2026-01-01T00:00:00+00:00")
    folder = tmp / "out" / train
    assert {p.name for p in paths} >= {TRAIN_CSV, TRAIN_PARQUET, "qctm_gp.json", "cavitation.json"}
    assert not (folder / TRAIN_CSV).read_text().startswith("#")  # a header row, then rows
    head = (folder / "gp_training.columns.csv").read_text().splitlines()
    assert any("decimation" in ln for ln in head) and any(ln.startswith("y_n,N,") for ln in head)
    import pyarrow.parquet as pq

    table = pq.read_table(folder / TRAIN_PARQUET)
    assert table.num_rows == len(res.training) and b"rigtool" in table.schema.metadata
    model = load_model(folder)
    assert model.noise is not None and model.window == PARAMS.window_blocks
    x = res.training.xf[:20]
    np.testing.assert_allclose(model.features(*res.training.x[:20].T)[:, [0, 2]], x[:, [0, 2]])
    mean, std = sklearn_predict(res.gp, x)
    np.testing.assert_allclose(model.correction(x)[0], mean, atol=1e-6)
    np.testing.assert_allclose(model.correction(x)[1], std, atol=1e-6)
    summary = json.loads((folder / "cavitation.json").read_text())
    assert summary["base_run_id"] == res.base_run_id
    html = render_report(store, res.run_id, None, image_format="png", cavitation=res)
    section = html[html.index('<section id="cavitation"'):]
    assert "Quasi-cavitation" in section and section.count("data:image/png") == 2
    assert 'id="cavitation-rates"' in section


def test_held_out_run_gp_beats_betm_alone(twin):
    """Smoke test on a tiny held-out run; the acceptance figures come from the benchmark."""
    tmp, store, _, _, test, res = twin
    model = load_model(tmp / "out" / res.run_id)
    ev = evaluate_on_run(store, test, model.predict, res.betm, PARAMS)

    def betm_only(n, i, h, segment=None):
        f = res.betm.fuse(n, i).thrust_n
        return f, f - 1, f + 1

    plain = evaluate_on_run(store, test, betm_only, res.betm, PARAMS)
    by = {c.name: c for c in ev.classes}
    base = {c.name: c for c in plain.classes}
    assert by["outside"].p95_abs_n <= 4.0
    assert by["event"].rms_n < base["event"].rms_n
    assert 0.7 <= ev.coverage95 <= 1.0


def test_report_renders_the_stored_cavitation_section_without_recomputing(twin, capsys,
                                                                         monkeypatch):
    tmp, store, _, train, _, _ = twin
    db, out = str(tmp / "db.sqlite"), str(tmp / "rep")
    assert main(["calibrate", train, "--db", db, "--out", out, "--causal"]) == 0
    calibrate_err = capsys.readouterr().err
    assert "causal (past-only) shortfall window misses" in calibrate_err
    assert "trained on this one run" in calibrate_err  # what a one-run model does on new runs
    before = store.events(train, "ventilation")

    def recompute(*args, **kwargs):
        raise AssertionError("report recomputed the calibration")

    monkeypatch.setattr("rigtool.analysis.calibrate.calibrate_run", recompute)
    monkeypatch.setattr("rigtool.analysis.calibrate.calibrate", recompute)
    monkeypatch.setattr("rigtool.analysis.cavitation.calibrate_cavitation", recompute)
    assert main(["report", train, "--db", db, "--out", out]) == 0
    assert capsys.readouterr().err == calibrate_err  # the same warnings, from the store
    html = (tmp / "rep" / train / "report.html").read_text()
    assert 'id="cavitation"' in html and "causal (past-only) shortfall window" in html
    assert store.events(train, "ventilation") == before  # only calibrate writes events


def test_one_point_shallow_run_calibrates(twin):
    tmp, store, base, _, _, _ = twin
    one = CAV.replace("values: [69, 90]", "values: [69]").replace("values: [20, 40]", "values: [20]")
    run = _sweep(tmp, one, "one.yaml", 34)
    res = calibrate_cavitation(store, run, base, PARAMS)
    assert "half of its one point" in res.evaluation.source
    assert np.isfinite(res.series["pred_n"]).all() and 0 < res.evaluation.coverage95 <= 1


def test_report_without_a_deep_base_run_warns_and_still_writes(tmp_path, capsys):
    run = _sweep(tmp_path, CAV, "cav.yaml", 33)
    args = [run, "--db", str(tmp_path / "db.sqlite"), "--out", str(tmp_path / "rep")]
    assert main(["calibrate", *args]) == 0
    capsys.readouterr()
    assert main(["report", *args]) == 0
    assert "no quasi-cavitation section" in capsys.readouterr().err
    assert 'id="cavitation"' not in (tmp_path / "rep" / run / "report.html").read_text()


def _exported(twin):
    tmp, _, _, train, _, res = twin
    folder = tmp / "out" / train
    if not (folder / "qctm_gp.json").exists():
        write_cavitation_artefacts(res, tmp / "out", created_utc="2026-01-01T00:00:00+00:00")
    return load_model(folder), res


def test_current_faults_fall_back_to_the_speed_estimate(twin):
    """A dropout (I = 0), a current below idle, and a current far above what the speed needs
    give the speed estimate, inside [0, f_n], with the fault flagged; never reversed thrust."""
    model, res = _exported(twin)
    n = np.full(10, float(np.median(res.training.x[:, 0])))
    i_hat = res.betm.c_n * n**3 + res.betm.i_0
    i = i_hat.copy()
    i[3] = 0.0  # dropout
    i[5] = 0.5 * res.betm.i_0  # below idle
    i[7] = 3.0 * i_hat[7]  # speed and current disagree
    p = model.evaluate(n, i, np.full(10, 0.3))
    f_n = res.betm.speed_estimate(n)
    for k in (3, 5, 7):
        assert p.flags[k] & CURRENT_FAULT
        assert 0.0 <= p.thrust_n[k] <= f_n[k]
        assert p.lo95[k] <= 0.0 and p.hi95[k] >= f_n[k]
    ok = [k for k in range(10) if k not in (3, 5, 7)]
    assert not np.any(p.flags[ok] & CURRENT_FAULT)
    # a fault is left out of its neighbours' shortfall window: they see a full current
    np.testing.assert_allclose(model.features(n, i, 0.3)[ok, 1], 0.0, atol=1e-9)
    assert np.all(p.thrust_n >= 0.0)


def test_no_reversed_thrust_for_a_forward_propeller(twin):
    model, res = _exported(twin)
    rng = np.random.default_rng(5)
    n = rng.uniform(50, 2500, 400)
    i = rng.uniform(0.0, 15.0, 400)
    h = rng.uniform(0.0, 1.5, 400)
    p = model.evaluate(n, i, h)
    f_b = res.betm.fuse(n, np.where(p.flags & CURRENT_FAULT, np.nan, i)).thrust_n
    assert np.all(p.thrust_n >= 0.0)
    assert np.all(p.thrust_n <= f_b + model.bounds.above_n + 1e-9)
    assert np.all((p.lo95 <= p.thrust_n) & (p.thrust_n <= p.hi95))


def test_inputs_outside_the_training_domain_are_flagged_and_widened(twin):
    model, res = _exported(twin)
    x = res.training.x
    inside = model.evaluate(x[:30, 0], x[:30, 1], x[:30, 2])
    assert not np.any(inside.flags & OUT_OF_DOMAIN)
    speed = float(x[:, 0].max()) * 1.4  # faster than any training block, current to match
    current = res.betm.c_n * speed**3 + res.betm.i_0
    far = model.evaluate(np.full(3, speed), np.full(3, current), np.array([0.3, 0.3, 2.0]))
    assert np.all(far.flags & OUT_OF_DOMAIN)
    f_b = res.betm.fuse(np.full(3, speed), np.full(3, current)).thrust_n
    assert np.all(far.lo95 <= 0.0) and np.all(far.hi95 >= f_b)
    doc = json.loads((twin[0] / "out" / res.run_id / "qctm_gp.json").read_text())
    assert set(doc["domain"]["ranges"]) == {"speed_rpm", "current_a", "depth_m",
                                            "shortfall_thrust_n"}
    assert doc["bounds"]["above_n"] >= 0.0



def test_calibrate_trains_the_model_on_several_runs(twin, capsys):
    """`--train-with` adds runs to the training set (what met the targets on new runs); the
    exported model names them, and the one-run warning goes away."""
    tmp, _, base, train, test, _ = twin
    db, out = str(tmp / "db.sqlite"), tmp / "multi"
    assert main(["calibrate", train, "--train-with", test, "--db", db, "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "trained on this one run" not in err
    doc = json.loads((out / train / "qctm_gp.json").read_text())
    assert sorted(doc["run_ids"]) == sorted([train, test])
    for bad, why in ((train, "being calibrated"), (base, "shallower"), ("nope", "no run")):
        assert main(["calibrate", train, "--train-with", bad, "--db", db, "--out",
                     str(tmp / "bad")]) == 2
        err = capsys.readouterr().err
        assert why in err and "Traceback" not in err
    assert not (tmp / "bad").exists()  # refused before any file
