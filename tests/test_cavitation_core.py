"""BETM fusion, event detection, training-set selection and GP export on synthetic data."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rigtool.analysis.betm_fit import split_variances
from rigtool.analysis.events import (
    EventParams,
    clip_to_windows,
    detect_events,
    match_events,
    relative_drop,
)
from rigtool.analysis.gp import (
    SIGNAL_SCALES,
    GpParams,
    cv_signal_scale,
    fit_exact,
    fit_hetero,
    sklearn_predict,
)
from rigtool.analysis.qctm_export import model_document
from rigtool.analysis.trainset import huber_weights, strata_keys, stratified_pick
from rigtool.models import (
    MODEL_FILE,
    VARIANCE_FILE,
    Z95,
    Betm,
    fuse_estimates,
    gp_features,
    load_model,
    window_mean,
)
from rigtool.models.domain import CLAMPED
from rigtool.models.qctm import gate

BETM = Betm(cp_fwd=2e-5, cp_rev=1.6e-5, c_n=1.2e-9, i_0=0.3, ci_fwd=17.0, ci_rev=13.6,
            sigma_n=0.1, sigma_i=1.0)


def test_fusion_is_inverse_variance_mean():
    est = fuse_estimates(np.array([10.0]), np.array([11.0]), 1.0, 4.0, 0.0, 1e12, 3.0)
    assert est.thrust_n[0] == pytest.approx((10 / 1 + 11 / 4) / (1 + 1 / 4))
    assert est.var[0] == pytest.approx(1 / (1 + 1 / 4 + 1e-12))
    assert est.consistent[0]


def test_prior_pulls_towards_u0():
    est = fuse_estimates(np.array([10.0]), np.array([10.0]), 1.0, 1.0, 0.0, 1.0, 3.0)
    assert est.thrust_n[0] == pytest.approx(20 / 3)


def test_consistency_test_drops_current_estimate():
    # d = |10 - 20| / sqrt(1 + 4) = 4.47 > 3: f_i dropped, fused = f_n (flat prior)
    est = fuse_estimates(np.array([10.0, 10.0]), np.array([20.0, 12.0]), 1.0, 4.0, 0.0, 1e12, 3.0)
    assert est.distance[0] == pytest.approx(10 / np.sqrt(5))
    assert not est.consistent[0] and est.consistent[1]
    assert est.thrust_n[0] == pytest.approx(10.0)
    nan = fuse_estimates(np.array([5.0]), np.array([np.nan]), 1.0, 1.0, 0.0, 1e12, 3.0)
    assert nan.thrust_n[0] == pytest.approx(5.0) and not nan.consistent[0]


def test_betm_models_and_sign():
    n = np.array([1000.0, -1000.0])
    assert BETM.speed_estimate(n) == pytest.approx([20.0, -16.0])
    f_i = BETM.current_estimate(np.array([1.3, 1.3]), n)
    assert f_i == pytest.approx([17.0, -13.6])
    fused = BETM.fuse(n, np.array([1.3, 1.3]))
    assert np.all(np.sign(fused.thrust_n) == np.sign(n))


def test_split_variances_recovers_components():
    rng = np.random.default_rng(0)
    m, en, ei = (rng.normal(0, s, 200_000) for s in (0.5, 0.1, 1.0))
    s_n, s_i, s_m = split_variances(m - en, m - ei)
    assert (s_n, s_i, s_m) == pytest.approx((0.1, 1.0, 0.5), rel=0.12)


def _series(events: list[tuple[float, float, float]], t_end: float = 20.0, dt: float = 0.1,
            seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(0.0, t_end, dt) + dt / 2
    drop = np.random.default_rng(seed).normal(0.0, 0.01, t.size)
    for a, b, d in events:
        drop[(t >= a) & (t < b)] += d
    return t, drop


def test_detect_none():
    t, r = _series([])
    assert detect_events(t, r, np.zeros(t.size)) == []


def test_detect_known_events_back_to_back_and_at_start():
    t, r = _series([(0.0, 2.0, 0.5), (5.0, 8.0, 0.3), (8.6, 10.0, 0.4), (15.0, 15.2, 0.5)])
    ev = detect_events(t, r, np.zeros(t.size), EventParams(min_gap_s=0.2))
    spans = [(round(e.t_start_s, 1), round(e.t_end_s, 1)) for e in ev]
    assert spans == [(0.0, 2.0), (5.0, 8.0), (8.6, 10.0)]  # 0.2 s blip below min duration
    assert ev[0].open_start and not ev[1].open_start
    assert ev[1].mean_drop == pytest.approx(0.3, abs=0.01)


def test_detect_bridges_short_gap_and_respects_segments():
    t, r = _series([(2.0, 4.0, 0.5), (4.1, 6.0, 0.5)])
    seg = (t > 5.0).astype(int)
    ev = detect_events(t, r, seg)
    assert [(round(e.t_start_s, 1), round(e.t_end_s, 1), e.segment) for e in ev] == [
        (2.0, 5.0, 0), (5.0, 6.0, 1)]
    assert ev[0].open_end and ev[1].open_start


def test_hysteresis_keeps_event_between_thresholds():
    t, r = _series([(2.0, 3.0, 0.2), (3.0, 6.0, 0.08)])
    ev = detect_events(t, r, np.zeros(t.size))
    assert len(ev) == 1 and ev[0].t_end_s == pytest.approx(6.0, abs=0.11)


def test_relative_drop_and_matching():
    assert np.isnan(relative_drop(np.array([1.0]), np.array([1.0]), 2.0))[0]
    assert relative_drop(np.array([5.0]), np.array([10.0]), 2.0)[0] == pytest.approx(0.5)
    truth = clip_to_windows([(1, 3), (9, 9.1), (20, 30)], [(0, 10)])
    m = match_events([(1.5, 2.5), (5, 6)], truth, 0.3)
    assert (m.n_true, m.n_true_found, m.n_false, m.n_true_short) == (1, 1, 1, 1)


def test_stratified_pick_bounds_and_balance():
    strata = np.array(["a"] * 1000 + ["b"] * 50 + ["c"] * 500)
    idx = stratified_pick(strata, 300)
    assert idx.size == 300 and np.all(np.diff(idx) > 0)
    counts = {k: int(np.sum(strata[idx] == k)) for k in "abc"}
    assert counts == {"a": 125, "b": 50, "c": 125}
    assert stratified_pick(strata, 5000).size == strata.size
    keys = strata_keys(np.array([0.2, 0.2]), np.array([40.0, 40.0]), np.array([True, False]))
    assert keys[0] != keys[1]


def test_huber_weights_downweight_outliers():
    y = np.random.default_rng(2).normal(0, 0.1, 400)
    y[100] += 5.0
    w, scale = huber_weights(y, np.zeros(y.size, int))
    assert w[100] < 0.1 and np.median(w) == 1.0 and 0.05 < scale < 0.2
    assert np.all((w > 0) & (w <= 1))


def _gp_data(n: int = 150, seed: int = 3) -> tuple[np.ndarray, ...]:
    """Raw (n, I, h) block means of 5 "points", their GP features, y and w; y's noise is
    10x larger where the current shortfall says ventilated."""
    rng = np.random.default_rng(seed)
    seg = np.repeat(np.arange(5), n // 5 + 1)[:n]
    speed = np.array([700.0, 1200.0, 1600.0, 1200.0, 1600.0])[seg] + rng.normal(0, 2, n)
    chunks = n // 10 + 1  # ventilated or not in runs of 10 blocks
    drop = np.repeat(np.where(rng.random(chunks) < 0.4, rng.uniform(0.25, 0.75, chunks), 0.0),
                     10)[:n]
    current = (BETM.c_n * speed**3 + BETM.i_0) * (1 - 0.08 * drop) + rng.normal(0, 0.01, n)
    depth = np.array([0.2, 0.3, 0.4, 0.2, 0.3])[seg]
    x = gp_features(BETM, speed, current, depth, seg, 3)
    y = -drop * BETM.speed_estimate(speed) + rng.normal(0, 0.1, n) * np.where(drop > 0, 10, 1)
    w = np.where(rng.random(n) < 0.1, 0.3, 1.0)
    return speed, current, depth, seg, x, y, w


def test_window_mean_and_features():
    v = np.arange(6.0)
    np.testing.assert_allclose(window_mean(v, None, 3), [0.5, 1, 2, 3, 4, 4.5])
    np.testing.assert_allclose(window_mean(v, np.array([0, 0, 0, 1, 1, 1]), 3),
                               [0.5, 1, 1.5, 3.5, 4, 4.5])
    np.testing.assert_allclose(window_mean(v, None, 1), v)
    # causal: past samples only, so a step shows up no earlier than it happens
    np.testing.assert_allclose(window_mean(v, None, 3, lead=0), [0, 0.5, 1, 2, 3, 4])
    step = np.r_[np.zeros(5), np.ones(5)]
    assert np.all(window_mean(step, None, 5, lead=0)[:5] == 0)
    assert window_mean(step, None, 5)[3] > 0
    n = np.array([1000.0, 1500.0])
    i = (BETM.c_n * n**3 + BETM.i_0) * np.array([1.0, 0.96])
    x = gp_features(BETM, n, i, 0.3)
    np.testing.assert_allclose(x[:, 1], [0.0, 0.04 * BETM.speed_estimate(1500.0)], atol=1e-12)


@pytest.mark.parametrize("hetero", [False, True])
def test_gp_export_reload_matches_sklearn(tmp_path, hetero):
    _, _, _, _, x, y, w = _gp_data()
    p = GpParams(hyper_n=150, n_restarts=0)
    t = np.arange(y.size) * 0.2
    gp = fit_hetero(x, y, w, np.floor(t / 2.0) % 2, p) if hetero else fit_exact(x, y, w, p)
    assert (gp.noise is not None) == hetero
    doc = model_document(BETM, gp, {"run_ids": ["synthetic"]}, window=3, block_s=0.2)
    assert doc["gp"]["signal"] == (not hetero)  # the default hetero fit keeps no signal
    (tmp_path / MODEL_FILE).write_text(json.dumps(doc))
    if doc["gp"]["signal"]:
        np.save(tmp_path / VARIANCE_FILE, gp.k_inv)
    model = load_model(tmp_path)
    assert model.window == 3
    speed, current, depth, seg, xq, _, _ = _gp_data(60, seed=4)
    mean_sk, std_sk = sklearn_predict(gp, xq)
    mean, std = model.correction(xq)
    np.testing.assert_allclose(mean, mean_sk, atol=1e-6)
    np.testing.assert_allclose(std, std_sk, atol=1e-6)
    np.testing.assert_allclose(gp.predict(xq)[1], std_sk, atol=1e-6)
    f, lo, hi = model.predict(speed, current, depth, seg)
    base = BETM.fuse(speed, current).thrust_n
    np.testing.assert_allclose(f, base + mean_sk, atol=1e-6)
    assert np.all(lo < f) and np.all(f < hi)
    # the documented C formulas: y_mean + sum_j a_j m(r_j); log var = log_mean + bias + ...
    g = doc["gp"]
    d = (xq[:1] - np.array(g["x_train"])) / (np.array(g["x_scale"]) * np.array(g["length_scales"]))
    s = np.sqrt(5.0) * np.sqrt((d**2).sum(axis=1))
    z = xq[0, 1]
    gate = 1.0 if g["gate_s"] == 0 else 1.0 / (1.0 + np.exp(-(abs(z) - g["gate_z0"]) / g["gate_s"]))
    a_n = np.array(g["a_n"]) if g["signal"] else 0.0  # no signal: no a_n, no kernel term
    c_mean = g["y_mean"] + g["beta"] * z * gate + np.sum(a_n * (1 + s + s * s / 3) * np.exp(-s))
    assert c_mean == pytest.approx(mean_sk[0], abs=1e-6)
    if hetero:
        nz = doc["noise"]
        d = (xq[:1] - np.array(nz["x_train"])) / (np.array(nz["x_scale"])
                                                  * np.array(nz["length_scales"]))
        s = np.sqrt(5.0) * np.sqrt((d**2).sum(axis=1))
        log_var = nz["log_mean"] + nz["log_bias"] + nz["signal_var"] * np.sum(
            np.array(nz["alpha"]) * (1 + s + s * s / 3) * np.exp(-s))
        assert np.exp(log_var) == pytest.approx(gp.noise_n2(xq[:1])[0], rel=1e-9)
        # larger noise where the shortfall says ventilated
        vent = np.abs(xq[:, 1]) > 1
        assert np.median(gp.noise_n2(xq[vent])) > 4 * np.median(gp.noise_n2(xq[~vent]))


def test_version_1_model_is_refused(tmp_path):
    (tmp_path / MODEL_FILE).write_text(json.dumps({"format": "rigtool-qctm-gp",
                                                   "format_version": 1}))
    with pytest.raises(ValueError, match="version-1"):
        load_model(tmp_path)


def test_causal_model_features_never_look_ahead(tmp_path):
    _, _, _, _, x, y, w = _gp_data()
    gp = fit_exact(x, y, w, GpParams(hyper_n=150, n_restarts=0))
    n = np.full(10, 1500.0)
    i = (BETM.c_n * n**3 + BETM.i_0) * np.r_[np.ones(5), np.full(5, 0.95)]  # shortfall from block 5
    for lead, ahead in ((0, False), (None, True)):
        doc = model_document(BETM, gp, {}, window=5, lead=lead)
        if lead is None:
            del doc["features"]["lead_blocks"]  # files written before the option read as centred
        (tmp_path / MODEL_FILE).write_text(json.dumps(doc))
        np.save(tmp_path / VARIANCE_FILE, gp.k_inv)
        z = load_model(tmp_path).features(n, i, 0.3)[:, 1]
        assert (z[3] > 0) == ahead and z[5] > 0


def test_point_folds_checkerboard_and_single_point_halves():
    from rigtool.analysis.cavitation import point_folds

    depth = np.repeat([0.2, 0.2, 0.4, 0.4], 3)
    command = np.repeat([69.0, 90.0, 69.0, 90.0], 3)
    assert point_folds(depth, command)[::3].tolist() == [0, 1, 1, 0]
    t = np.tile([0.1, 0.3, 0.5], 4)
    one = point_folds(np.full(6, 0.3), np.full(6, 69.0), np.arange(6.0))
    assert one.tolist() == [0, 0, 0, 1, 1, 1] and point_folds(depth, command, t).tolist() == \
        point_folds(depth, command).tolist()


def test_fit_hetero_refuses_fold_labels_other_than_0_1():
    _, _, _, _, x, y, w = _gp_data()
    with pytest.raises(ValueError, match="fold"):
        fit_hetero(x, y, w, np.arange(y.size) % 3, GpParams(hyper_n=100, n_restarts=0))


def test_gated_mean_only_when_it_helps():
    from rigtool.analysis.gp import fit_gated_mean

    rng = np.random.default_rng(0)
    z = np.r_[rng.normal(0, 0.05, 400), rng.uniform(0.5, 3.0, 200)]  # noise, then events
    y = np.where(np.arange(600) < 400, 0.0, -12.5 * z) + rng.normal(0, 0.2, 600)
    g = fit_gated_mean(z, y, np.ones(600))
    assert g.s > 0 and g.beta == pytest.approx(-12.5, rel=0.05) and 0.05 < g.z0 < 0.6
    assert abs(g(np.array([0.05]))[0]) < 0.1 and g(np.array([2.0]))[0] == pytest.approx(-25, rel=0.05)
    lin = fit_gated_mean(np.linspace(-1, 1, 50), 3.0 * np.linspace(-1, 1, 50), np.ones(50))
    assert lin.s == 0 and lin.beta == pytest.approx(3.0)
    with pytest.raises(ValueError, match="finite"):
        fit_gated_mean(np.array([np.nan, 1.0]), np.zeros(2), np.ones(2))


def test_newer_model_format_is_refused(tmp_path):
    _, _, _, _, x, y, w = _gp_data()
    doc = model_document(BETM, fit_exact(x, y, w, GpParams(hyper_n=100, n_restarts=0)), {})
    doc["format_version"] += 1
    (tmp_path / MODEL_FILE).write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="update rigtool"):
        load_model(tmp_path)


def test_cv_signal_scale_trusts_a_gp_less_on_noise_and_keeps_it_on_signal():
    from rigtool.analysis.gp import Hyper, cv_signal_scale, fit_noise

    rng = np.random.default_rng(3)
    x = rng.uniform(-1, 1, (300, 3))
    fold = (x[:, 0] > 0).astype(int)
    hyper = Hyper(np.full(3, 0.3), 5.0, 0.0)  # short and strong: fits whatever it sees
    p = GpParams(hyper_n=100, n_restarts=0, signal_scales=SIGNAL_SCALES)
    noise_y = rng.normal(0, 1.0, 300)
    noise = fit_noise(x, noise_y, p)
    assert cv_signal_scale(x, noise_y, np.ones(300), fold, hyper, noise, p) < 1.0
    smooth = np.sin(3 * x[:, 1]) * 5 + rng.normal(0, 0.1, 300)
    noise = fit_noise(x, smooth - np.sin(3 * x[:, 1]) * 5, p)
    assert cv_signal_scale(x, smooth, np.ones(300), fold, Hyper(np.full(3, 1.0), 5.0, 0.0),
                           noise, p) > 0.0  # a GP that predicts what it never saw is kept


def test_window_mean_leaves_out_invalid_blocks():
    v = np.array([1.0, 1.0, 100.0, 1.0, 1.0])
    valid = np.array([True, True, False, True, True])
    np.testing.assert_allclose(window_mean(v, None, 3, valid=valid), [1, 1, 1, 1, 1])
    assert window_mean(v, None, 1, valid=valid)[2] == 0.0  # no valid block in its window


def test_signal_scale_takes_the_simplest_model_cv_cannot_tell_apart():
    """With a target the GP cannot learn (pure noise), every factor fits equally badly: the
    one-standard-error rule returns the smallest signal variance, not a noise-driven pick."""
    rng = np.random.default_rng(11)
    x = np.column_stack([rng.uniform(500, 1500, 240), rng.normal(0, 0.05, 240),
                         np.repeat([0.2, 0.3, 0.4, 0.55], 60)])
    y = rng.normal(0, 0.3, 240)
    w = np.ones(240)
    groups = np.repeat(np.arange(8), 30)
    fold = groups % 2
    p = GpParams(hyper_n=120, n_restarts=0, signal_scales=SIGNAL_SCALES)
    h = fit_exact(x, y, w, p, keep_inverse=False).hyper
    noise = fit_hetero(x, y, w, fold, p).noise
    assert cv_signal_scale(x, y, w, fold, h, noise, p, groups) == min(SIGNAL_SCALES)


def test_run_folds_see_what_point_folds_miss():
    """Two runs whose residuals follow each run's own smooth pattern (events and tares of
    that run): a check on held-out points of the same runs rewards a GP that learnt them;
    a check on the other run finds that the mean term alone (factor 0) does as well."""
    rng = np.random.default_rng(21)
    n_pts, per = 12, 20
    grid = np.column_stack([np.repeat(np.linspace(600, 1600, 4), 3), rng.uniform(0, 2, n_pts),
                            np.tile([0.2, 0.3, 0.4], 4)])
    x = np.repeat(grid, per, axis=0) + rng.normal(0, [5, 0.05, 0], (n_pts * per, 3))
    x = np.vstack([x, x])
    run = np.repeat([0, 1], n_pts * per)
    phase = np.where(run == 0, 0.0, 2.0)
    y = 2.0 * np.sin(x[:, 0] / 150 + phase) + rng.normal(0, 0.2, len(x))
    w = np.ones(len(x))
    point = np.tile(np.repeat(np.arange(n_pts), per), 2) + n_pts * run
    p = GpParams(hyper_n=150, n_restarts=0, signal_scales=SIGNAL_SCALES)
    h = fit_exact(x, y, w, p, keep_inverse=False).hyper
    by_point = np.tile(np.repeat(np.arange(n_pts) % 2, per), 2)
    noise = fit_hetero(x, y, w, run, p).noise
    assert cv_signal_scale(x, y, w, by_point, h, noise, p, point) > 0.0
    assert cv_signal_scale(x, y, w, run, h, noise, p, point) == 0.0


def test_by_default_the_model_is_the_mean_term_alone():
    """The default fit keeps no GP signal: its mean is y_mean + g(z) wherever it is asked."""
    _, _, _, seg, x, y, w = _gp_data(200, seed=4)
    gp = fit_hetero(x, y, w, seg % 2, GpParams(hyper_n=100, n_restarts=0), seg)
    assert gp.signal_scale == 0.0 and gp.hyper.signal_var == 0.0
    far = x + np.array([300.0, 0.0, 0.1])
    for rows in (x, far):
        np.testing.assert_allclose(gp.predict(rows)[0], gp.y_mean + gp.mean_term(rows[:, 1]),
                                   atol=1e-9)


def test_training_folds_hold_out_whole_runs():
    from rigtool.analysis.cavitation import training_folds
    from rigtool.analysis.trainset import TrainingSet

    def ts(run_ids):
        k = len(run_ids)
        return TrainingSet(x=np.column_stack([np.full(k, 900.0), np.ones(k),
                                              np.tile([0.2, 0.3], k // 2)]),
                           xf=np.zeros((k, 3)), y=np.zeros(k), w=np.ones(k), t_s=np.arange(k),
                           command=np.repeat([40.0, 69.0], k // 2), ventilated=np.zeros(k, bool),
                           thrust_n=np.zeros(k), betm_n=np.zeros(k), run_id=np.array(run_ids))
    assert training_folds(ts(["a", "b", "c", "a", "b", "c"])).tolist() == [0, 1, 0, 0, 1, 0]
    one = training_folds(ts(["a"] * 4))
    assert sorted(set(one.tolist())) == [0, 1]  # one run: the checkerboard of points


def test_noise_bias_covers_quiet_and_ventilating_rows_apart():
    """Each group (quiet, ventilating by the gate) gets its own bias, and fresh data from the
    same source is covered in both groups (86-91 % here: five points give a rough
    cross-fit), not one group at the other's expense."""
    _, _, _, seg, x, y, w = _gp_data(300, seed=8)
    gp = fit_hetero(x, y, w, seg % 2, GpParams(hyper_n=150, n_restarts=0), seg)
    noise = gp.noise
    assert noise is not None and noise.log_bias_event is not None
    assert noise.log_bias_event > noise.log_bias  # the ventilating rows are the noisier
    _, _, _, _, xt, yt, _ = _gp_data(1500, seed=9)
    mean, std = gp.predict(xt)
    inside = np.abs(yt - mean) <= Z95 * std
    vent = gate(xt[:, 1], noise.gate_z0, noise.gate_s) >= 0.5
    for group in (vent, ~vent):
        assert group.sum() > 100 and 0.85 <= inside[group].mean() <= 0.995


def _synthetic_model(tmp_path, **doc_changes):
    _, _, _, seg, x, y, w = _gp_data()
    gp = fit_hetero(x, y, w, seg % 2, GpParams(hyper_n=150, n_restarts=0), seg)
    doc = model_document(BETM, gp, {}, window=3, block_s=0.2)
    doc.update(doc_changes)
    (tmp_path / MODEL_FILE).write_text(json.dumps(doc))
    if doc["gp"]["signal"]:
        np.save(tmp_path / VARIANCE_FILE, gp.k_inv)
    return load_model(tmp_path), gp


def test_edge_inputs_of_the_run_time_model(tmp_path):
    """An infinite above_n survives JSON (as null); an empty domain flags nothing; a block
    without speed is NaN, not 'clamped', and stays out of its neighbours' windows."""
    model, _ = _synthetic_model(tmp_path, bounds={"shortfall": [-0.2, 0.3], "above_n": None},
                                domain={"ranges": {}, "max_distance": 1e9})
    assert model.bounds.above_n == np.inf
    n = np.array([1200.0, np.nan, 1200.0, 1200.0])
    i = BETM.c_n * np.nan_to_num(n, nan=1200.0) ** 3 + BETM.i_0
    p = model.evaluate(n, i, np.full(4, 0.3), np.zeros(4))
    assert np.isnan(p.thrust_n[1]) and not p.flags[1] & CLAMPED
    assert np.all(np.isfinite(p.thrust_n[[0, 2, 3]])) and not np.any(p.flags[[0, 2, 3]] & 1)
    np.testing.assert_allclose(model.features(n, i, 0.3)[[0, 2], 1], 0.0, atol=1e-9)


def test_a_variance_file_of_another_fit_is_refused(tmp_path):
    _synthetic_model(tmp_path)
    np.save(tmp_path / VARIANCE_FILE, np.eye(3))
    with pytest.raises(ValueError, match="another fit"):
        load_model(tmp_path)
