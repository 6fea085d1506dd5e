"""Held-out check of the QCTM-GP's 95 % intervals (run-fold, block-fold), the stated floor,
and where they are written; synthetic data and small twin runs."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from rigtool.analysis.cavitation import (
    CHECK_LEVEL,
    ONE_RUN_WARNING,
    OUT_OF_REACH,
    OUTSIDE_CHECK_LEVEL,
    block_folds,
    calibrate_cavitation,
    check_folds,
    check_warnings,
    evaluate_on_run,
    floor_range,
    floor_verdict,
    mixture_p95,
    thrust_model,
)
from rigtool.analysis.gp import (
    MAX_NOISE_SIGNAL_VAR,
    SHIFT_RANGE,
    GateShift,
    GpParams,
    calibrate_gate,
    shift_noise,
    upper_quantile,
)
from rigtool.analysis.results import CavitationParams
from rigtool.analysis.trainset import TrainingSet
from rigtool.cli import main
from rigtool.models import Z95
from rigtool.models.qctm import LogNoise
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
CAV = (Path(__file__).resolve().parents[1] / "protocols" / "luo2020-cavitation.yaml").read_text()
PARAMS = CavitationParams(budget=1000, gp=GpParams(hyper_n=250, n_restarts=0))
TRAIN_SEEDS, HELD_OUT_SEEDS = (61, 62), (71, 72, 73, 74, 75, 76)


def _sweep(tmp: Path, text: str, name: str, seed: int) -> str:
    path = tmp / name
    path.write_text(text)
    assert main(["sweep", str(path), "--sim", "--seed", str(seed), "--db",
                 str(tmp / "db.sqlite")]) == 0
    return Store(tmp / "db.sqlite").runs(limit=1)[0]["id"]


@pytest.fixture(scope="module")
def twin(tmp_path_factory):
    """A base run, two training runs and six held-out runs of the shipped cavitation protocol
    (12 points of 25 s); models from one run and from two."""
    tmp = tmp_path_factory.mktemp("intervals")
    _sweep(tmp, BASE, "base.yaml", 7)
    train = [_sweep(tmp, CAV, "cav.yaml", s) for s in TRAIN_SEEDS]
    held = [_sweep(tmp, CAV, "cav.yaml", s) for s in HELD_OUT_SEEDS]
    store = Store(tmp / "db.sqlite")
    one = calibrate_cavitation(store, train[0], None, PARAMS)
    two = calibrate_cavitation(store, train[0], None, PARAMS, train_with=[train[1]])
    return tmp, store, train, held, one, two


def _held_out_coverage(store: Store, res, runs: list[str]) -> dict[str, float]:
    """Coverage of the exported model's intervals per class, pooled over held-out runs."""
    model = thrust_model(res.betm, res.gp, res.training, PARAMS)
    inside = {"event": [0.0, 0], "outside": [0.0, 0]}
    for run in runs:
        ev = evaluate_on_run(store, run, model.predict, res.betm, PARAMS)
        for c in ev.classes:
            if c.name in inside:
                inside[c.name][0] += c.coverage95 * c.n
                inside[c.name][1] += c.n
    return {k: v[0] / v[1] for k, v in inside.items()}


@pytest.mark.parametrize("which", ["one", "two"])
def test_intervals_hold_on_held_out_runs(twin, which):
    """Single-run (block-fold) and two-run (run-fold) models: 90-98 % of held-out blocks
    during events and outside them lie inside the 95 % intervals."""
    _, store, _, held, one, two = twin
    res = one if which == "one" else two
    assert res.interval_check["kind"] == ("block" if which == "one" else "run")
    cover = _held_out_coverage(store, res, held)
    assert 0.90 <= cover["event"] <= 0.98, cover
    assert 0.90 <= cover["outside"] <= 0.98, cover


def test_single_run_warns_and_two_runs_do_not(twin):
    _, _, _, _, one, two = twin
    assert ONE_RUN_WARNING in one.warnings and "block-fold" in ONE_RUN_WARNING
    assert ONE_RUN_WARNING not in two.warnings
    assert two.interval_check["folds"] == 2 and one.interval_check["folds"] == 4


def test_floor_in_cavitation_json_and_report(twin):
    """`calibrate --report` writes the floor and the interval check to cavitation.json (and
    the model file) and shows them in the report; `report` shows them from the store."""
    tmp, _, train, _, _, _ = twin
    db, out = str(tmp / "db.sqlite"), tmp / "out"
    assert main(["calibrate", train[0], "--db", db, "--out", str(out), "--report"]) == 0
    summary = json.loads((out / train[0] / "cavitation.json").read_text())
    for name in ("event", "outside"):
        floor = summary["floor"]["classes"][name]
        assert floor["floor_p95_n"] > 0 and floor["heldout_p95_n"] >= floor["floor_p95_n"]
        assert floor["target_p95_n"] in (3.5, 1.0) and floor["verdict"]
        low, high = floor["floor_range_n"]
        assert low <= floor["floor_p95_n"] <= high and floor["floor_groups"] >= 2
        assert 0 < summary["interval_check"]["classes"][name]["coverage"] <= 1
    assert summary["interval_check"]["check_levels"] == {"event": CHECK_LEVEL,
                                                         "outside": OUTSIDE_CHECK_LEVEL}
    model = json.loads((out / train[0] / "qctm_gp.json").read_text())
    assert model["floor"] == summary["floor"]
    _model_carries_the_check(model, summary["interval_check"])
    for html in ((out / train[0] / "report.html").read_text(),):
        section = html[html.index('<section id="cavitation"'):]
        assert 'id="cavitation-floor"' in section and "floor p95 N" in section
        assert "one training run, so never checked on another run" in section
    assert main(["report", train[0], "--db", db, "--out", str(tmp / "rep")]) == 0
    assert 'id="cavitation-floor"' in (tmp / "rep" / train[0] / "report.html").read_text()


def _model_carries_the_check(model: dict, check: dict) -> None:
    """What `calibrate` exports is what its check set (issue 29: a widening seen in the bench
    never reached the CLI's model): format 7, the loss-side table of the check (absent when
    it is 0 at every speed), the noise GP within its bounds, and no shift at the limit."""
    assert model["format_version"] == 7
    noise, missed = model["noise"], check["missed_lower"]
    if any(v > 0 for v in missed["lower_n"]):
        assert noise["missed_speed_rpm"] == pytest.approx(missed["speed_rpm"], rel=1e-6)
        assert noise["missed_lower_n"] == pytest.approx(missed["lower_n"], rel=1e-6, abs=1e-6)
    else:
        assert "missed_lower_n" not in noise
    assert noise["signal_var"] <= MAX_NOISE_SIGNAL_VAR
    assert max(abs(v) for v in check["log_var_shift"].values()) < SHIFT_RANGE - 1


def _training_set(run_id: np.ndarray, depth: np.ndarray, command: np.ndarray,
                  t_s: np.ndarray) -> TrainingSet:
    k = len(run_id)
    return TrainingSet(x=np.column_stack([np.full(k, 900.0), np.ones(k), depth]),
                       xf=np.zeros((k, 3)), y=np.zeros(k), w=np.ones(k), t_s=t_s,
                       command=command, ventilated=np.zeros(k, bool), thrust_n=np.zeros(k),
                       betm_n=np.zeros(k), run_id=run_id)


def test_folds_hold_out_whole_runs_or_slices_of_every_point():
    t = np.tile(np.arange(20) * 0.2, 3)
    depth, command = np.repeat([0.2, 0.2, 0.4], 20), np.repeat([69.0, 90.0, 69.0], 20)
    runs = _training_set(np.repeat(["a", "b", "c"], 20), depth, command, t)
    fold, kind = check_folds(runs)
    assert kind == "run" and fold.tolist() == np.repeat([0, 1, 2], 20).tolist()
    one = _training_set(np.full(60, "a"), depth, command, t + np.repeat([0, 10, 20], 20))
    fold, kind = check_folds(one)
    assert kind == "block" and np.array_equal(fold, block_folds(one))
    for p in range(3):  # every point is cut into 4 contiguous slices, one per fold
        f = fold[20 * p:20 * (p + 1)]
        assert sorted(set(f.tolist())) == [0, 1, 2, 3] and np.count_nonzero(np.diff(f)) == 3


def test_calibrate_gate_covers_both_classes_on_fresh_data():
    """Quiet rows whose model variance is too wide and ventilating rows whose variance is too
    narrow: after the shifts both are covered at 95 %, also on new rows of the same kind."""
    rng = np.random.default_rng(5)

    def rows(n: int) -> tuple[np.ndarray, ...]:
        event = rng.random(n) < 0.3
        z = np.where(event, rng.uniform(1.0, 3.0, n), rng.normal(0.0, 0.05, n))
        resid = rng.normal(0.0, np.where(event, 3.0, 0.3))
        noise = np.where(event, 1.5, 0.6) ** 2  # the model's variance, wrong in both classes
        return resid, noise, z, event

    resid, noise, z, event = rows(4000)
    shift = calibrate_gate(resid, np.zeros(resid.size), noise, z, event, ~event, 0.5, 0.1)
    assert shift.d_event > 0 > shift.d_quiet
    resid, noise, z, event = rows(4000)
    inside = resid**2 <= Z95**2 * noise * shift.factor(z)
    assert 0.93 <= inside[event].mean() <= 0.97 and 0.93 <= inside[~event].mean() <= 0.97


def test_outside_check_level_sets_the_quiet_scale_alone():
    """With its own target outside events, the quiet shift covers that fraction of the held-out
    outside rows (not 95 %), and the event shift still covers 95 % of the event rows."""
    assert 0.9 < OUTSIDE_CHECK_LEVEL < CHECK_LEVEL == 0.95
    rng = np.random.default_rng(11)
    n = 6000
    event = rng.random(n) < 0.3
    z = np.where(event, rng.uniform(1.0, 3.0, n), rng.normal(0.0, 0.05, n))
    resid = rng.normal(0.0, np.where(event, 3.0, 0.3))
    noise = np.where(event, 1.5, 0.6) ** 2
    post = np.zeros(n)
    same = calibrate_gate(resid, post, noise, z, event, ~event, 0.5, 0.1, CHECK_LEVEL)
    own = calibrate_gate(resid, post, noise, z, event, ~event, 0.5, 0.1, CHECK_LEVEL,
                         OUTSIDE_CHECK_LEVEL)
    assert own.d_quiet < same.d_quiet
    for shift, quiet_level in ((same, CHECK_LEVEL), (own, OUTSIDE_CHECK_LEVEL)):
        inside = resid**2 <= Z95**2 * noise * shift.factor(z)
        assert inside[~event].mean() == pytest.approx(quiet_level, abs=0.003)
        assert inside[event].mean() == pytest.approx(CHECK_LEVEL, abs=0.005)


def test_shifted_noise_model_is_the_calibrated_one():
    """The exported noise model (biases shifted, same format) gives exactly the variance the
    check calibrated: var times GateShift.factor; a model without a gate takes the shift's."""
    rng = np.random.default_rng(2)
    x = rng.normal(size=(40, 3))
    q = rng.normal(size=(25, 3))
    for event_bias in (1.1, None):
        noise = LogNoise(np.zeros(3), np.ones(3), np.ones(3), 0.7, -1.0, x,
                         rng.normal(size=40), 0.3, event_bias, 0.4, 0.1)
        shift = GateShift(0.4, 0.1, -0.5, 0.8)
        expected = noise.var_n2(q) * shift.factor(q[:, 1])
        np.testing.assert_allclose(shift_noise(noise, shift).var_n2(q), expected, rtol=1e-12)


def test_the_floor_range_narrows_with_more_groups_and_brackets_the_truth():
    """Groups (points) whose sds scatter as one run's events do: the floor's range from 8 groups
    is 1.5-2 times as wide as from 64, and over seeded trainings it holds the floor of the
    population the groups came from 65-75 % of the time with 8 groups and 84-89 % with 64 (a
    bootstrap's percentile range under-covers: read it as the least uncertainty there is)."""
    rng = np.random.default_rng(21)
    population = np.exp(rng.normal(0.5, 0.6, 20000))
    truth = mixture_p95(population)
    widths, held = {}, {}
    for n in (8, 64):
        spans, hits = [], []
        for k in range(100):
            sd, rows = rng.choice(population, n), rng.integers(5, 40, n)
            low, high = floor_range(sd, rows, np.random.default_rng(k))
            spans.append(high - low)
            hits.append(low <= truth <= high)
        widths[n], held[n] = float(np.median(spans)), float(np.mean(hits))
    assert widths[8] > 1.3 * widths[64] > 0
    assert 0.55 <= held[8] < held[64] and 0.78 <= held[64] <= 0.95
    assert all(math.isnan(v) for v in floor_range(np.ones(1), np.ones(1, int), rng))


def test_out_of_reach_only_when_the_whole_floor_range_is_above_the_target():
    """A floor from one run's few events is uncertain (a factor of 3 between trainings of one
    thruster): only a range wholly above the target is "out of reach" (and warned about)."""
    assert floor_verdict((4.0, 5.0, 6.5), 7.0, 3.5) == OUT_OF_REACH
    assert floor_verdict((math.nan, 5.0, math.nan), 7.0, 3.5) == OUT_OF_REACH  # a lone group
    spans = floor_verdict((2.0, 3.9, 6.0), 7.0, 3.5)
    assert spans != OUT_OF_REACH and "spans the target" in spans
    assert floor_verdict((2.0, 3.9, 6.0), 3.0, 3.5) == "target met on held-out data"
    assert "not ruled out" in floor_verdict((0.5, 1.0, 2.0), 7.0, 3.5)
    floor = {"classes": {"event": {"verdict": spans, "floor_p95_n": 3.9, "target_p95_n": 3.5},
                         "outside": {"verdict": OUT_OF_REACH, "floor_p95_n": 1.4,
                                     "floor_range_n": [1.2, 1.7], "target_p95_n": 1.0}}}
    (warning,) = check_warnings(_check(0.95, 1.0), floor)
    assert warning.startswith("outside events") and "range 1.20-1.70 N" in warning


def test_mixture_p95():
    assert mixture_p95(np.full(10, 2.0)) == pytest.approx(Z95 * 2.0, rel=1e-6)
    assert np.isnan(mixture_p95(np.zeros(0)))


def _check(event_cov: float, event_shift: float) -> dict:
    classes = {"event": {"n_blocks": 200, "coverage": event_cov},
               "outside": {"n_blocks": 900, "coverage": 0.95}}
    return {"classes": classes, "n_events": 40,
            "log_var_shift": {"event": event_shift, "outside": 0.1},
            "sd_factor": {"event": math.exp(event_shift / 2), "outside": math.exp(0.05)}}


def test_a_check_that_misses_or_hits_the_widening_limit_says_so():
    """Found by an attack: a held-out check at 82.6 % against its 95 %, and event intervals
    widened to the limit (sd x 20, +-68 N), both passed without a word."""
    floor = {"classes": {c: {"verdict": "target met on held-out data"}
                         for c in ("event", "outside")}}
    assert check_warnings(_check(0.95, 1.0), floor) == []
    narrow = check_warnings(_check(0.826, 1.0), floor)
    assert len(narrow) == 1 and "during events" in narrow[0] and "82.6 %" in narrow[0]
    capped = check_warnings(_check(0.917, SHIFT_RANGE), floor)
    assert len(capped) == 1 and "widening limit (sd x 20.1)" in capped[0]


def test_missed_ventilation_is_covered_by_the_loss_side_widening_alone():
    """Event rows whose shortfall the gate calls quiet (a thrust loss the current misses, here
    at the slow level only): a loss-side widening at that level covers them on new rows, the
    fast level gets none, and outside rows stay at their target (the widening is one-sided)."""
    rng = np.random.default_rng(13)

    def rows(n: int) -> tuple[np.ndarray, ...]:
        slow = rng.random(n) < 0.5
        speed = np.where(slow, 800.0, 1500.0) + rng.normal(0.0, 5.0, n)
        event = rng.random(n) < 0.3
        missed = event & slow & (rng.random(n) < 0.4)
        z = np.where(event & ~missed, rng.uniform(1.0, 3.0, n), rng.normal(0.0, 0.05, n))
        resid = rng.normal(0.0, np.where(event & ~missed, 3.0, 0.3))
        resid = np.where(missed, -rng.uniform(1.5, 5.0, n), resid)  # a loss, never a gain
        return speed, np.where(slow, 40.0, 90.0), z, resid, event

    speed, level, z, resid, event = rows(8000)
    noise = np.where(event, 1.5, 0.6) ** 2
    shift = calibrate_gate(resid, np.zeros(resid.size), noise, z, event, ~event, 0.5, 0.1,
                           CHECK_LEVEL, OUTSIDE_CHECK_LEVEL, speed_rpm=speed, speed_level=level)
    slow_knot, fast_knot = shift.missed_lower_n
    assert 3.5 < slow_knot < 6.0 and fast_knot == 0.0
    plain = calibrate_gate(resid, np.zeros(resid.size), noise, z, event, ~event, 0.5, 0.1,
                           CHECK_LEVEL, OUTSIDE_CHECK_LEVEL)
    speed, level, z, resid, event = rows(8000)
    noise = np.where(event, 1.5, 0.6) ** 2
    for s, lo_event in ((shift, 0.93), (plain, 0.0)):
        half = Z95 * np.sqrt(noise * s.factor(z))
        inside = (resid <= half) & (-resid <= half + s.missed(speed, z))
        assert inside[event].mean() >= lo_event
        assert 0.91 <= inside[~event].mean() <= 0.97
    assert inside[event].mean() < 0.93  # without the widening the missed losses fall out


def test_a_level_that_saw_too_little_ventilation_gets_the_loss_it_can_cause():
    """A training whose slow level saw only a few events, all gated, while the gate misses
    most ventilation at the middle level: the slow level gets the loss ventilation can cause
    there (its quiet thrust times the loss share) beyond the half-width; it used to get 0,
    and a new run ventilating there, unseen by the gate, fell out. The fast level, where the
    gate saw every one of many events, keeps 0."""
    rng = np.random.default_rng(29)
    knots_rpm = np.array([700.0, 1200.0, 1600.0])

    def rows(n: int, slow_events: float) -> tuple[np.ndarray, ...]:
        k = rng.integers(0, 3, n)
        speed = knots_rpm[k] + rng.normal(0.0, 5.0, n)
        thrust = 10.0 * (speed / 1000.0) ** 2
        event = rng.random(n) < np.array([slow_events, 0.3, 0.3])[k]
        missed = event & (k < 2) & (rng.random(n) < np.array([1.0, 0.7, 0.0])[k])
        z = np.where(event & ~missed, rng.uniform(1.0, 3.0, n), rng.normal(0.0, 0.05, n))
        resid = rng.normal(0.0, np.where(event & ~missed, 3.0, 0.3))
        resid = np.where(missed, -rng.uniform(0.3, 0.8, n) * thrust, resid)
        return speed, np.array([40.0, 69.0, 90.0])[k], z, resid, event, missed, thrust

    speed, level, z, resid, event, _, thrust = rows(6000, 0.0)
    seen = (level == 40.0) & (np.cumsum(level == 40.0) <= 10)
    event, z = event | seen, np.where(seen, 2.0, z)  # 10 event rows there, all gated
    noise = np.where(event, 1.5, 0.6) ** 2
    args = (resid, np.zeros(resid.size), noise, z, event, ~event, 0.5, 0.1, CHECK_LEVEL,
            OUTSIDE_CHECK_LEVEL)
    shift = calibrate_gate(*args, speed_rpm=speed, speed_level=level, loss_cap_n=0.8 * thrust)
    slow, mid, fast = shift.missed_lower_n
    assert mid > 1.0 and fast == 0.0
    assert 1.5 < slow < 0.8 * 4.9
    assert calibrate_gate(*args, speed_rpm=speed, speed_level=level).missed_lower_n[0] == 0.0
    speed, level, z, resid, event, missed, _ = rows(6000, 0.3)  # a new run ventilating at 40 %
    half = Z95 * np.sqrt(noise.mean() * shift.factor(z))
    lost = missed & (level == 40.0)
    assert np.mean(-resid[lost] <= half[lost] + shift.missed(speed[lost], z[lost])) >= 0.9
    assert np.mean(-resid[lost] <= half[lost]) < 0.5  # with 0 it was mostly outside


def test_upper_quantile_is_a_small_sample_bound():
    """The bound is the largest value for few rows, at or above the sample quantile, and
    above the population's 95 % quantile in about 90 % of samples of 200."""
    rng = np.random.default_rng(5)
    x = rng.exponential(size=20)
    assert upper_quantile(x, 0.95) == x.max()
    true_q95 = -math.log(0.05)
    draws = [rng.exponential(size=200) for _ in range(400)]
    above = np.mean([upper_quantile(d, 0.95) >= true_q95 for d in draws])
    assert all(upper_quantile(d, 0.95) >= np.quantile(d, 0.95) for d in draws[:50])
    assert 0.85 <= above <= 0.97


def _binned_mean(z: np.ndarray, y: np.ndarray, bins: int = 20) -> np.ndarray:
    """Mean of y in quantile bins of z, at every row (an in-sample E[y | z])."""
    edges = np.unique(np.quantile(z, np.linspace(0, 1, bins + 1)))
    k = np.clip(np.searchsorted(edges, z, side="right") - 1, 0, edges.size - 2)
    return np.array([y[k == j].mean() for j in range(edges.size - 1)])[k]


@pytest.mark.parametrize("which", ["one", "two"])
def test_mean_term_error_during_events_is_what_the_signals_allow(twin, which):
    """The exported mean during the twin's TRUE events on held-out runs: beta is the twin's
    -1 / cav_current_drop (z noise does not shrink it), and its error there is no more above
    the measured thrust than that of the best mean from (z, command) fitted on the held-out
    blocks themselves: conditioning on the truth, not the mean term, makes it look biased
    (research/cavitation-log.md, 'Where the mean term's error during events comes from')."""
    from types import SimpleNamespace

    from rigtool.analysis.cavitation import training_blocks
    from rigtool.analysis.cavitation_truth import truth_intervals
    from rigtool.analysis.dataset import load_run
    from rigtool.thruster_profiles import ThrusterProfile

    _, store, _, held, one, two = twin
    res = one if which == "one" else two
    assert res.gp.mean_term.beta == pytest.approx(-1.0 / ThrusterProfile.cav_current_drop,
                                                  rel=0.05)
    sets = []
    for run in held:
        truth = [SimpleNamespace(t_start_s=a, t_end_s=b) for a, b in truth_intervals(store, run)]
        sets.append(training_blocks(load_run(store, run), res.betm, truth, PARAMS)[0])
    z, y = (np.concatenate([getattr(s, k) for s in sets]) for k in ("xf", "y"))
    z = z[:, 1]
    cls, cmd = (np.concatenate([getattr(s, k) for s in sets]) for k in ("block_class", "command"))
    use = (cls == "event") | (cls == "outside")
    best = np.full(y.size, np.nan)
    for c in np.unique(cmd):
        best[use & (cmd == c)] = _binned_mean(z[use & (cmd == c)], y[use & (cmd == c)])
    model = res.gp.predict(np.concatenate([s.xf for s in sets]))[0]
    ev = cls == "event"
    # one-sided: the finding was an estimate above the measured thrust; on the dev set the
    # exported mean was 0.6 N below to 0.8 N above that optimum per training
    assert np.mean((model - y)[ev]) - np.mean((best - y)[ev]) <= 1.0
