"""The reference C evaluator (rigtool/models/c) against rigtool.models on the same block means.

Agreement: |C - Python| <= 1e-7 N + 1e-12 |Python| for thrust, lo95 and hi95 (the sums over
training rows run in a different order than numpy's BLAS; with smooth kernels they cancel to
several 1e-9 N), identical flags and NaNs.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

import rigtool.models
from rigtool.analysis.blocks import block_means
from rigtool.analysis.cavitation import calibrate_cavitation
from rigtool.analysis.dataset import load_run
from rigtool.analysis.gp import GpParams, fit_exact, fit_hetero
from rigtool.analysis.qctm_export import model_document
from rigtool.analysis.results import CavitationParams
from rigtool.artefacts.cavitation import write_cavitation_artefacts
from rigtool.cli import main
from rigtool.models import (
    CLAMPED,
    CURRENT_FAULT,
    MODEL_FILE,
    OUT_OF_DOMAIN,
    VARIANCE_FILE,
    Betm,
    Bounds,
    Domain,
    gp_features,
    load_model,
)
from rigtool.store import Store

CC = shutil.which("cc") or shutil.which("gcc")
pytestmark = pytest.mark.skipif(CC is None, reason="no C compiler")
C_DIR = Path(rigtool.models.__file__).parent / "c"
ATOL, RTOL = 1e-7, 1e-12

BASE = """rigtool_protocol: 1
name: mini-baseline
simulator: {profile: can-bldc, seed: 7}
metadata: {thruster_id: bldc-350w}
command: {unit: percent, range: {start: -100, stop: 100, step: 20}, order: up}
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
timing: {settle: {seconds: 1.0}, acquire: {seconds: 8, rate_hz: 250}, rest_s: 1.0,
         tare: per_depth}
limits: {max_thrust_n: 90, max_current_a: 12, max_speed_rpm: 2000, slew_per_s: 200}
"""
# a full GP signal, so the posterior sums of the C evaluator are exercised on a twin model
# (the default fit keeps none: the synthetic "slim" model below; "hetero" keeps one)
PARAMS = CavitationParams(budget=120, gp=GpParams(hyper_n=120, n_restarts=0,
                                                  signal_scales=(1.0,)))
BETM = Betm(cp_fwd=2e-5, cp_rev=1.6e-5, c_n=1.2e-9, i_0=0.3, ci_fwd=17.0, ci_rev=13.6,
            sigma_n=0.1, sigma_i=1.0)
BETM_LEVELS = Betm(cp_fwd=2e-5, cp_rev=1.6e-5, c_n=1.2e-9, i_0=0.3, ci_fwd=17.0, ci_rev=13.6,
                   sigma_n=0.1, sigma_i=1.0, u0=0.5, sigma0=50.0, level_n=(2.0, 10.0, 30.0),
                   sigma_n_level=(0.05, 0.1, 0.4), sigma_i_level=(2.0, 1.0, 0.6))


@pytest.fixture(scope="module")
def qctm_eval(tmp_path_factory) -> Path:
    """The command-line program, built with the line documented in qctm_gp.c."""
    exe = tmp_path_factory.mktemp("cbuild") / "qctm_eval"
    subprocess.run([CC, "-std=c99", "-O2", "-Wall", "-Wextra", "-o", str(exe),
                    str(C_DIR / "qctm_gp.c"), str(C_DIR / "qctm_eval_main.c"), "-lm"],
                   check=True, capture_output=True, text=True)
    return exe


def _sweep(tmp: Path, text: str, name: str, seed: int) -> str:
    path = tmp / name
    path.write_text(text)
    assert main(["sweep", str(path), "--sim", "--seed", str(seed), "--db", str(tmp / "db.sqlite")]) == 0
    return Store(tmp / "db.sqlite").runs(limit=1)[0]["id"]


@pytest.fixture(scope="module")
def twin(tmp_path_factory) -> tuple[Path, dict, Betm]:
    """A twin-trained model folder, the recorded block means of a held-out run, its BETM."""
    tmp = tmp_path_factory.mktemp("ctwin")
    base = _sweep(tmp, BASE, "base.yaml", 7)
    train = _sweep(tmp, CAV, "cav.yaml", 31)
    test = _sweep(tmp, CAV, "cav.yaml", 32)
    store = Store(tmp / "db.sqlite")
    res = calibrate_cavitation(store, train, base, PARAMS)
    write_cavitation_artefacts(res, tmp / "out", created_utc="2026-01-01T00:00:00+00:00")
    b = block_means(load_run(store, test), PARAMS.train_block_s)
    rec = {"speed": b.speed_rpm, "current": b.current_a, "depth": b.depth_m,
           "segment": b.point.astype(int), "train": res.training.x}
    return tmp / "out" / train, rec, res.betm


def _run_c(exe: Path, folder: Path, n, i, h, seg) -> np.ndarray:
    """(thrust_n, lo95, hi95, flags) rows from the C program."""
    lines = [f"{float(a)!r},{float(b)!r},{float(c)!r},{s}" for a, b, c, s in zip(n, i, h, seg, strict=True)]
    out = subprocess.run([str(exe), str(folder)], input="speed_rpm,current_a,depth_m,segment\n"
                         + "\n".join(lines) + "\n", capture_output=True, text=True, check=True)
    rows = [[float(v) for v in ln.split(",")] for ln in out.stdout.splitlines()]
    return np.array(rows).reshape(-1, 4)


def _agree(exe: Path, folder: Path, n, i, h, seg) -> tuple[float, np.ndarray]:
    """Assert C and load_model(folder).evaluate agree; return the max abs difference, flags."""
    c = _run_c(exe, folder, n, i, h, seg)
    p = load_model(folder).evaluate(n, i, h, np.asarray(seg))
    assert c.shape == (len(p.thrust_n), 4)
    worst = 0.0
    for col, ref in enumerate((p.thrust_n, p.lo95, p.hi95)):
        np.testing.assert_array_equal(np.isnan(c[:, col]), np.isnan(ref))
        ok = ~np.isnan(ref)
        diff = np.abs(c[ok, col] - ref[ok])
        assert np.all(diff <= ATOL + RTOL * np.abs(ref[ok])), (col, diff.max())
        worst = max(worst, float(diff.max(initial=0.0)))
    np.testing.assert_array_equal(c[:, 3].astype(int), p.flags)
    return worst, p.flags


def _mixed(rec: dict, betm: Betm) -> tuple[np.ndarray, ...]:
    """Recorded blocks (several segments) with faults and out-of-range inputs spliced in,
    then the training rows, each as its own segment."""
    n, i, h = (np.array(rec[k], dtype=float) for k in ("speed", "current", "depth"))
    seg = list(rec["segment"])
    i[[3, 4]] = 0.0  # dropout, two blocks
    i[9] = 0.5 * betm.i_0  # below idle
    i[14] = np.nan  # no current reading
    i[17] = np.inf
    i[21] = 3.0 * (betm.c_n * n[21] ** 3 + betm.i_0)  # speed and current disagree
    n[25] *= 1.4  # faster than any training block, current to match
    i[25] = betm.c_n * n[25] ** 3 + betm.i_0
    h[27] = 2.0  # deeper than the training runs
    n[30], i[30] = -n[30], i[30]  # reverse
    n[33] = np.nan
    h[35] = np.nan
    n[38] = 0.0
    x = rec["train"]
    return (np.r_[n, x[:, 0]], np.r_[i, x[:, 1]], np.r_[h, x[:, 2]],
            np.r_[seg, 1000 + np.arange(len(x))])


def test_twin_model_agrees_with_python(qctm_eval, twin):
    folder, rec, betm = twin
    worst, flags = _agree(qctm_eval, folder, *_mixed(rec, betm))
    assert worst < ATOL
    assert all(np.any(flags & bit) for bit in (OUT_OF_DOMAIN, CURRENT_FAULT))
    assert np.sum(flags == 0) > len(flags) // 2  # mostly ordinary blocks


def test_twin_model_as_format_5_without_kinv_uses_the_prior_variance(qctm_eval, twin,
                                                                      tmp_path):
    """Before format 6 the posterior-variance file was optional (format 6 says whether)."""
    folder, rec, betm = twin
    doc = json.loads((folder / MODEL_FILE).read_text())
    assert doc["gp"].pop("signal") is True
    (tmp_path / MODEL_FILE).write_text(json.dumps({**doc, "format_version": 5}))
    inputs = _mixed(rec, betm)
    _agree(qctm_eval, tmp_path, *inputs)
    post, prior = _run_c(qctm_eval, folder, *inputs), _run_c(qctm_eval, tmp_path, *inputs)
    ok = ~np.isnan(post[:, 0])
    assert np.all(prior[ok, 2] - prior[ok, 1] >= post[ok, 2] - post[ok, 1] - 1e-9)
    assert np.any(prior[ok, 2] - prior[ok, 1] > post[ok, 2] - post[ok, 1] + 1e-6)


def _gp_data(n: int, seed: int, betm: Betm = BETM) -> tuple[np.ndarray, ...]:
    """Block means of 5 "points", GP features (window 3), y and w; noisier when ventilated."""
    rng = np.random.default_rng(seed)
    seg = np.repeat(np.arange(5), n // 5 + 1)[:n]
    speed = np.array([700.0, 1200.0, 1600.0, 1200.0, 1600.0])[seg] + rng.normal(0, 2, n)
    drop = np.repeat(np.where(rng.random(n // 10 + 1) < 0.4,
                              rng.uniform(0.25, 0.75, n // 10 + 1), 0.0), 10)[:n]
    current = (betm.c_n * speed**3 + betm.i_0) * (1 - 0.08 * drop) + rng.normal(0, 0.01, n)
    depth = np.array([0.2, 0.3, 0.4, 0.2, 0.3])[seg]
    x = gp_features(betm, speed, current, depth, seg, 3)
    y = -drop * betm.speed_estimate(speed) + rng.normal(0, 0.1, n) * np.where(drop > 0, 10, 1)
    return speed, current, depth, seg, x, y, np.where(rng.random(n) < 0.1, 0.3, 1.0)


def _synthetic(folder: Path, case: str) -> Betm:
    """Write a synthetic model: "hetero" (a GP signal kept, centred window, no bounds:
    above_n is Infinity in the JSON, no domain), "slim" (the default fit: no GP signal, so
    no posterior-variance file) or "exact" (causal, BETM level tables, bounds and domain)."""
    betm = BETM_LEVELS if case == "exact" else BETM
    _, _, _, _, x, y, w = _gp_data(100, 3, betm)
    p = GpParams(hyper_n=100, n_restarts=0)
    if case == "exact":
        gp = fit_exact(x, y, w, p)
        domain = Domain({"speed_rpm": (650.0, 1650.0), "current_a": (0.5, 5.5),
                         "depth_m": (0.15, 0.45), "shortfall_thrust_n": (-1.0, 30.0)}, 1.5)
        doc = model_document(betm, gp, {}, window=5, lead=0, bounds=Bounds((-0.2, 0.3), 2.0),
                             domain=domain)
    else:
        if case == "hetero":
            p = GpParams(hyper_n=100, n_restarts=0, signal_scales=(1.0,))
        gp = fit_hetero(x, y, w, np.floor(np.arange(y.size) * 0.1) % 2, p)
        doc = model_document(betm, gp, {}, window=3)
    assert doc["gp"]["signal"] == (case != "slim")
    (folder / MODEL_FILE).write_text(json.dumps(doc))
    if doc["gp"]["signal"]:
        np.save(folder / VARIANCE_FILE, gp.k_inv)
    return betm


def _as_version_2(doc: dict) -> dict:
    """A format-2 file: plain beta z, centred window, no bounds, domain or flags."""
    doc["format_version"] = 2
    for key in ("bounds", "domain", "flags"):
        del doc[key]
    del doc["features"]["lead_blocks"]
    for key in ("gate_z0", "gate_s", "signal"):
        del doc["gp"][key]
    return doc


@pytest.fixture(scope="module")
def hetero_files(tmp_path_factory) -> tuple[str, bytes]:
    """Text of a synthetic model file and its posterior-variance file, fitted once."""
    folder = tmp_path_factory.mktemp("chetero")
    _synthetic(folder, "hetero")
    return (folder / MODEL_FILE).read_text(), (folder / VARIANCE_FILE).read_bytes()


@pytest.mark.parametrize("case", ["hetero", "slim", "exact", "v2"])
def test_synthetic_models_agree_with_python(qctm_eval, hetero_files, tmp_path, case):
    if case in ("exact", "slim"):
        betm = _synthetic(tmp_path, case)
    else:  # the module's hetero model, as it is or as a version-2 file
        doc = json.loads(hetero_files[0])
        (tmp_path / MODEL_FILE).write_text(json.dumps(_as_version_2(doc) if case == "v2" else doc))
        (tmp_path / VARIANCE_FILE).write_bytes(hetero_files[1])
        betm = BETM
    speed, current, depth, seg, *_ = _gp_data(80, 4, betm)
    rec = {"speed": speed, "current": current, "depth": depth, "segment": seg,
           "train": np.column_stack(_gp_data(20, 5, betm)[:3])}
    n, i, h, s = _mixed(rec, betm)
    n[[40, 41]] = [150.0, -300.0]  # below the first BETM level knot
    worst, flags = _agree(qctm_eval, tmp_path, n, i, h, s)
    assert worst < ATOL and np.any(flags & CURRENT_FAULT)
    if case == "exact":
        assert np.any(flags & CLAMPED) and np.any(flags & OUT_OF_DOMAIN)
    if case == "v2":  # before format 6 the file is optional: the prior variance without it
        (tmp_path / VARIANCE_FILE).unlink()
        _agree(qctm_eval, tmp_path, n, i, h, s)


FIXTURE = Path(__file__).parent / "fixtures" / "qctm_v5"  # written by the format-5 writer


def test_format_5_file_with_kinv_evaluates_as_the_format_5_reader_did(qctm_eval, tmp_path):
    """A small format-5 model (GP signal, qctm_gp_kinv.npy) and the format-5 reader's output:
    both readers still load it and give that output."""
    assert json.loads((FIXTURE / MODEL_FILE).read_text())["format_version"] == 5
    want = np.genfromtxt(FIXTURE / "expected.csv", delimiter=",", names=True)
    n, i, h, seg = (want[k] for k in ("speed_rpm", "current_a", "depth_m", "segment"))
    seg = seg.astype(int)
    model = load_model(FIXTURE)
    assert model.k_inv is not None and model.alpha is not None
    p = model.evaluate(n, i, h, seg)
    for got, col in ((p.thrust_n, "thrust_n"), (p.lo95, "lo95"), (p.hi95, "hi95")):
        np.testing.assert_allclose(got, want[col], rtol=1e-12, atol=1e-9)
    np.testing.assert_array_equal(p.flags, want["flags"].astype(int))
    _agree(qctm_eval, FIXTURE, n, i, h, seg)
    shutil.copy(FIXTURE / MODEL_FILE, tmp_path / MODEL_FILE)  # format 5 without kinv: prior
    assert load_model(tmp_path).k_inv is None
    _agree(qctm_eval, tmp_path, n, i, h, seg)


def _both_refuse(exe: Path, folder: Path, words: str) -> None:
    """The C program exits 1 with a one-line message and load_model raises, both with `words`."""
    out = subprocess.run([str(exe), str(folder)], input="1000,1,0.3,0\n",
                         capture_output=True, text=True)
    assert out.returncode == 1 and out.stdout == "" and len(out.stderr.splitlines()) == 1
    assert words in out.stderr, out.stderr
    with pytest.raises(ValueError, match=words):
        load_model(folder)


@pytest.fixture(scope="module")
def slim_text(tmp_path_factory) -> str:
    """Text of a synthetic model without GP signal (format 6, "signal": false)."""
    folder = tmp_path_factory.mktemp("cslim")
    _synthetic(folder, "slim")
    assert not (folder / VARIANCE_FILE).exists()
    return (folder / MODEL_FILE).read_text()


def test_the_signal_flag_must_match_the_fields_and_files(qctm_eval, hetero_files, slim_text,
                                                         tmp_path):
    """Format 6: gp.signal false with a variance file, alpha or a signal variance, or true
    without them, is refused by both readers."""
    text, kinv = hetero_files
    (tmp_path / MODEL_FILE).write_text(slim_text)
    (tmp_path / VARIANCE_FILE).write_bytes(kinv)  # an earlier fit's file left in the folder
    _both_refuse(qctm_eval, tmp_path, "belongs to another fit")
    (tmp_path / VARIANCE_FILE).unlink()
    cases = [(slim_text, '"signal": false', '"signal": true', "gp.alpha is missing"),
             (slim_text, '"signal": false', '"signal": 0', "gp.signal must be true or false"),
             (slim_text, '"signal_var": 0.0', '"signal_var": 1e-9', "signal_var"),
             (slim_text, '"signal": false', '"signal": false, "a_n": [1]', "gp.a_n is present"),
             (text, '"signal": true', '"signal": false', "gp.alpha is present")]
    for base, old, new, words in cases:
        assert old in base
        (tmp_path / MODEL_FILE).write_text(base.replace(old, new, 1))
        _both_refuse(qctm_eval, tmp_path, words)
    (tmp_path / MODEL_FILE).write_text(text)  # a GP signal without its variance file
    _both_refuse(qctm_eval, tmp_path, "is missing")
    (tmp_path / VARIANCE_FILE).write_bytes(kinv)
    _agree(qctm_eval, tmp_path, np.array([1000.0]), np.array([1.5]), np.array([0.3]), [0])


@pytest.mark.parametrize("field", ["log_mean", "log_bias"])
@pytest.mark.parametrize("value", ["1e308", "-1e308", "150.5"])
def test_a_noise_level_that_is_no_log_variance_is_refused_by_both(qctm_eval, slim_text,
                                                                 tmp_path, field, value):
    """A log-variance level of 1e308 (or beyond +-100) would give infinite or NaN intervals:
    both readers refuse the file instead (found by an attack)."""
    text, n = re.subn(rf'"{field}": [^,}}]+', f'"{field}": {value}', slim_text, count=1)
    assert n == 1
    (tmp_path / MODEL_FILE).write_text(text)
    _both_refuse(qctm_eval, tmp_path, "not a finite log variance")


NAN, INF = float("nan"), float("inf")


def _write_with(folder: Path, text: str, section: str, field: str, value: object,
                column: int) -> None:
    """The model `text` with one field of `section` replaced (x_train: the value in `column`
    of its first row; alpha: its first value), written to `folder`."""
    doc = json.loads(text)
    part = doc[section]
    if field == "x_train":
        part["x_train"][0][column] = value
    elif field == "alpha":
        part["alpha"][0] = value
    else:
        part[field] = value
    (folder / MODEL_FILE).write_text(json.dumps(doc))


@pytest.mark.parametrize("field, value", [
    ("gate_z0", NAN), ("gate_s", NAN), ("gate_s", INF), ("signal_var", NAN),
    ("signal_var", 1e308), ("signal_var", -1.0), ("x_mean", [NAN, 0.0, 0.0]),
    ("x_scale", [1.0, 0.0, 1.0]), ("length_scales", [INF, 1.0, 1.0]), ("x_train", NAN),
    ("alpha", INF)])
def test_a_noise_field_that_is_not_finite_is_refused_by_both(qctm_eval, slim_text, tmp_path,
                                                            field, value):
    """NaN or inf in the noise model's gate, signal variance, inputs or weights gave NaN or
    infinite intervals (and gate_s NaN made Python and C disagree): both readers refuse the
    file instead (found by an attack). x_train and alpha: one value of the first row."""
    _write_with(tmp_path, slim_text, "noise", field, value, column=1)
    _both_refuse(qctm_eval, tmp_path, f"noise.{field}")


@pytest.mark.parametrize("section, field, value", [
    ("noise", "x_mean", [1e200, 0.0, 0.0]), ("noise", "x_scale", [1e-300, 1.0, 1.0]),
    ("noise", "length_scales", [1.0, 1e-300, 1.0]), ("noise", "x_train", 1e300),
    ("noise", "alpha", 1e300), ("gp", "x_mean", [0.0, 1e200, 0.0]),
    ("gp", "x_scale", [1.0, 1.0, 1e-300]), ("gp", "length_scales", [1e300, 1.0, 1.0]),
    ("gp", "x_train", -1e300), ("gp", "y_mean", 1e300), ("gp", "y_std", 1e200),
    ("gp", "y_std", 0.0), ("gp", "noise_var", -5.0), ("gp", "beta", -1e300),
    ("gp", "gate_s", 1e300)])
def test_a_finite_but_extreme_model_field_is_refused_by_both(qctm_eval, slim_text, tmp_path,
                                                             section, field, value):
    """Finite values so extreme that standardising or squaring them overflows (x_mean 1e200,
    x_scale 1e-300) gave NaN intervals in Python, and in C for x_scale; y_std 1e200 an
    OverflowError at prediction; the gp section's levels were not checked at all (found by
    an attack). Both readers refuse them, naming the field. x_train: one value."""
    _write_with(tmp_path, slim_text, section, field, value, column=0)
    _both_refuse(qctm_eval, tmp_path, f"{section}.{field}")


def test_missed_ventilation_widening_agrees_and_acts_on_the_loss_side_only(qctm_eval, slim_text,
                                                                         tmp_path):
    """Format 7: the loss-side widening (noise.missed_*) lowers lo95 in forward and raises
    hi95 in reverse, by (1 - gate) times the table at |speed|, in C as in Python; a table
    that is not increasing, or whose lengths differ, is refused by both."""
    doc = json.loads(slim_text)
    (tmp_path / MODEL_FILE).write_text(json.dumps(doc))
    speed, current, depth, seg, *_ = _gp_data(80, 4, BETM)
    n = np.r_[speed, -speed[:10]]
    i, h, s = np.r_[current, current[:10]], np.r_[depth, depth[:10]], np.r_[seg, 9 + seg[:10]]
    plain = load_model(tmp_path).evaluate(n, i, h, s)
    doc["noise"].update(missed_speed_rpm=[700.0, 1200.0, 1600.0], missed_lower_n=[4.0, 1.0, 0.0])
    (tmp_path / MODEL_FILE).write_text(json.dumps(doc))
    model = load_model(tmp_path)
    wide = model.evaluate(n, i, h, s)
    worst, _ = _agree(qctm_eval, tmp_path, n, i, h, s)
    assert worst < ATOL
    want = model.noise.missed_lower(model.features(n, i, h, s))
    fwd = n > 0
    np.testing.assert_allclose(plain.lo95[fwd] - wide.lo95[fwd], want[fwd], atol=1e-12)
    np.testing.assert_allclose(wide.hi95[~fwd] - plain.hi95[~fwd], want[~fwd], atol=1e-12)
    np.testing.assert_array_equal(wide.hi95[fwd], plain.hi95[fwd])
    np.testing.assert_array_equal(wide.thrust_n, plain.thrust_n)
    slow = fwd & (np.abs(n - 700) < 50)
    assert np.median(want[slow]) > 2.0 and np.all(want[np.abs(n) > 1590] < 0.1)
    for knots, lower in (([700.0, 700.0, 1600.0], [4.0, 1.0, 0.0]), ([700.0], [4.0, 1.0]),
                         ([700.0, 1200.0], [4.0, -1.0])):
        doc["noise"].update(missed_speed_rpm=knots, missed_lower_n=lower)
        (tmp_path / MODEL_FILE).write_text(json.dumps(doc))
        _both_refuse(qctm_eval, tmp_path, "missed")


BAD_DOCS = {
    "empty": lambda t: "",
    "truncated": lambda t: t[: len(t) // 2],
    "trailing": lambda t: t + " x",
    "nested": lambda t: "[" * 100000,
    "bad number": lambda t: t.replace('"y_std": ', '"y_std": 1.', 1),
    "bad escape": lambda t: t.replace('"rigtool-qctm-gp"', '"rigtool\\q"', 1),
    "not an object": lambda t: "[1, 2, 3]",
    "version 1": lambda t: t.replace('"format_version": 7', '"format_version": 1', 1),
    "version 8": lambda t: t.replace('"format_version": 7', '"format_version": 8', 1),
    "x_train type": lambda t: t.replace('"x_train": [', '"x_train": "no", "x": [', 1),
    "unknown betm field": lambda t: t.replace('"cp_fwd"', '"cp_sideways": 1, "cp_fwd"', 1),
}


@pytest.mark.parametrize("name", sorted(BAD_DOCS))
def test_malformed_model_exits_with_a_message(qctm_eval, hetero_files, tmp_path, name):
    (tmp_path / MODEL_FILE).write_text(BAD_DOCS[name](hetero_files[0]))
    out = subprocess.run([str(qctm_eval), str(tmp_path)], input="1000,1,0.3,0\n",
                         capture_output=True, text=True)
    assert out.returncode == 1 and out.stdout == ""
    assert out.stderr.startswith("qctm_eval: ") and len(out.stderr.splitlines()) == 1


def test_bad_kinv_and_bad_input_exit_with_a_message(qctm_eval, hetero_files, tmp_path):
    text, good = hetero_files
    (tmp_path / MODEL_FILE).write_text(text)
    (tmp_path / VARIANCE_FILE).write_bytes(good[:200])
    out = subprocess.run([str(qctm_eval), str(tmp_path)], input="", capture_output=True,
                         text=True)
    assert out.returncode == 1 and VARIANCE_FILE in out.stderr
    (tmp_path / VARIANCE_FILE).write_bytes(good)
    out = subprocess.run([str(qctm_eval), str(tmp_path / MODEL_FILE)],
                         input="1000,1,0.3,0\n1000,abc,0.3,0\n", capture_output=True, text=True)
    assert out.returncode == 2 and "line 2" in out.stderr and out.stdout == ""


@pytest.mark.parametrize("bad", [np.nan, np.inf, -1e200])
def test_a_variance_file_with_a_bad_entry_is_refused_by_both_readers(qctm_eval, hetero_files,
                                                                     tmp_path, bad):
    """One non-finite or absurd entry in qctm_gp_kinv.npy would make every posterior variance
    NaN (or negative, clipped to 0): both readers refuse the file and name it."""
    text, good = hetero_files
    (tmp_path / MODEL_FILE).write_text(text)
    (tmp_path / VARIANCE_FILE).write_bytes(good)
    k_inv = np.load(tmp_path / VARIANCE_FILE)
    k_inv[3, 5] = bad
    np.save(tmp_path / VARIANCE_FILE, k_inv)
    _both_refuse(qctm_eval, tmp_path, f"{VARIANCE_FILE}: entries must be finite")


def test_calibrate_writes_no_unused_gp_terms_and_both_readers_agree(qctm_eval, twin, tmp_path,
                                                                    capsys):
    """`rigtool calibrate` with the default fit (no GP signal): format 7 without the
    posterior-variance file or the signal arrays, an earlier fit's file in the folder
    removed, and the C program and rigtool.models agree on it."""
    folder, rec, betm = twin
    out = tmp_path / folder.name
    out.mkdir()
    shutil.copy(folder / VARIANCE_FILE, out / VARIANCE_FILE)  # left by an earlier calibrate
    assert main(["calibrate", folder.name, "--db", str(folder.parent.parent / "db.sqlite"),
                 "--out", str(tmp_path)]) == 0
    capsys.readouterr()
    doc = json.loads((out / MODEL_FILE).read_text())
    assert doc["format_version"] == 7 and doc["gp"]["signal"] is False
    assert doc["gp"]["signal_var"] == 0 and not {"alpha", "a_n", "weights"} & set(doc["gp"])
    assert not (out / VARIANCE_FILE).exists()
    assert load_model(out).alpha is None
    worst, flags = _agree(qctm_eval, out, *_mixed(rec, betm))
    assert worst < ATOL and np.any(flags & CURRENT_FAULT)


def test_a_one_run_model_says_its_intervals_are_not_validated(qctm_eval, twin, tmp_path):
    """Issue 47 item 9: trained on one run, cavitation.json, the model file, load_model and
    the C evaluator all say its 95 % intervals were not validated on another run; a model
    that says true gets no note, and a flag that is not a boolean is refused by both."""
    folder = twin[0]
    summary = json.loads((folder / "cavitation.json").read_text())["training"]
    assert summary["training_runs"] == 1 and summary["intervals_validated"] is False
    doc = json.loads((folder / MODEL_FILE).read_text())
    assert doc["training_runs"] == 1 and doc["intervals_validated"] is False
    assert load_model(folder).intervals_validated is False
    out = subprocess.run([str(qctm_eval), str(folder)], input="1000,1,0.3,0\n",
                         capture_output=True, text=True, check=True)
    assert "not validated" in out.stderr
    for value, note in ((True, False), ("yes", None)):
        shutil.copy(folder / VARIANCE_FILE, tmp_path / VARIANCE_FILE)
        (tmp_path / MODEL_FILE).write_text(json.dumps({**doc, "intervals_validated": value}))
        if note is None:
            _both_refuse(qctm_eval, tmp_path, "intervals_validated")
            continue
        assert load_model(tmp_path).intervals_validated is True
        out = subprocess.run([str(qctm_eval), str(tmp_path)], input="1000,1,0.3,0\n",
                             capture_output=True, text=True, check=True)
        assert out.stderr == ""
