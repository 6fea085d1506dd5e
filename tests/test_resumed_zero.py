"""A resumed sweep's sensor zero: one offset per session, one drift for all (fits.ZeroLine).

Sweeps on the twin through the CLI, stopped by Ctrl-C (SIGINT) after a point, resumed with
`rigtool sweep --resume` and calibrated, against the same seed uninterrupted. The twin is
opened again at a resume: by default its offset starts over (as a re-opened sensor, or a box
zeroing itself, would); `continuing` makes it carry on as if never stopped.
"""

from __future__ import annotations

import json
import math
import os
import signal
from pathlib import Path

import numpy as np
import pytest
import yaml

from rigtool.analysis.calibrate import calibrate_run
from rigtool.analysis.fits import ZeroLine, fit_thrust_speed
from rigtool.analysis.results import CalibrationResult
from rigtool.cli import main
from rigtool.progress import SilentReporter
from rigtool.sim import physics
from rigtool.store import Store
from rigtool.thruster_profiles import PROFILES

from .conftest import PROTOCOLS

pytestmark = pytest.mark.usefixtures("terminal_signals")  # sweeps stopped by Ctrl-C and resumed

BLDC = """\
rigtool_protocol: 1
name: bldc-resume
simulator: {{profile: can-bldc, seed: 1, overrides: {{drift_n_per_h: {drift}}}}}
command: {{unit: percent, range: {{start: -100, stop: 100, step: 1}}, order: up}}
depth: {{unit: m, values: [1.0], mode: preset}}
timing: {{settle: {{seconds: 2.0}}, acquire: {{samples: 2000, rate_hz: 1000}}, rest_s: 1.0,
         tare: {tare}, tare_s: 1.0}}
limits: {{max_thrust_n: 90, max_current_a: 12, max_speed_rpm: 2000, slew_per_s: 200}}
"""
LUO = (PROTOCOLS / "luo2020-baseline.yaml").read_text()
SHIPPED_LUO_SEED = yaml.safe_load(LUO)["simulator"]["seed"]
ESC = (PROTOCOLS / "esc-1100-1900.yaml").read_text()
STM32 = (PROTOCOLS / "stm32-pwm.yaml").read_text()
MODEL = ("C_p_fwd", "C_p_rev", "C_n", "C_i_fwd_direct", "C_i_rev_direct")


def _ctrl_c_after(k: int) -> type:
    """A reporter class that presses Ctrl-C (SIGINT to this process) once point k is stored."""

    class CtrlCAfter(SilentReporter):
        def step_done(self, step, thrust_n) -> None:
            if step.idx == k:
                os.kill(os.getpid(), signal.SIGINT)

    return CtrlCAfter


class _Continuing(physics.ThrusterTwin):
    """A twin whose offset and drift carry on from the run's start (`SHIFT_S` earlier)."""

    SHIFT_S = 0.0

    def __init__(self, *args, t0: float = 0.0, **kwargs) -> None:
        super().__init__(*args, t0=t0 - self.SHIFT_S, **kwargs)


def _sweep(tmp: Path, text: str, seed: int, stop_after: int | None = None,
           continuing: bool = False) -> tuple[Store, str]:
    """Sweep `text` with `seed` through the CLI, stopped after point `stop_after` and resumed
    (the twin's offset starting over, or `continuing`); the store and the run id."""
    db = tmp / f"{seed}-{stop_after}-{continuing}.sqlite"
    path = tmp / "protocol.yaml"
    path.write_text(text)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr("rigtool.cli.sweep.default_reporter",
                   SilentReporter if stop_after is None else _ctrl_c_after(stop_after))
        code = main(["sweep", str(path), "--sim", "--db", str(db), "--seed", str(seed)])
        assert code == (0 if stop_after is None else 130)
        store = Store(db)
        run_id = store.resolve_run_id("last")
        if stop_after is not None:
            mp.setattr("rigtool.cli.sweep.default_reporter", SilentReporter)
            if continuing:
                t_used = max(s["t_end_s"] for s in store.steps(run_id))
                mp.setattr(_Continuing, "SHIFT_S", t_used + 1.0)
                mp.setattr(physics, "ThrusterTwin", _Continuing)
            assert main(["sweep", "--resume", run_id, "--db", str(db)]) == 0
            assert store.run(run_id)["status"] == "completed"
    return store, run_id


@pytest.fixture(scope="module")
def uninterrupted() -> dict[tuple[str, int], CalibrationResult]:
    """Calibrations of uninterrupted runs by (protocol text, seed), made once for the module:
    cases that differ only in how they resume share one (it is read, never changed)."""
    return {}


def _pair(tmp: Path, text: str, seed: int, stop_after: int, done: dict,
          continuing: bool = False) -> tuple[CalibrationResult, CalibrationResult]:
    """Calibrations of the uninterrupted run (from `done`, the `uninterrupted` fixture, when
    another case made it) and of the interrupted and resumed one."""
    if (text, seed) not in done:
        done[text, seed] = calibrate_run(*_sweep(tmp, text, seed))
    resumed = calibrate_run(*_sweep(tmp, text, seed, stop_after, continuing))
    return done[text, seed], resumed


def _drift(cal: CalibrationResult) -> tuple[float, float, float]:
    """(value, lo, hi) of the calibration's zero drift (N/h), from its single section."""
    (sec,) = cal.sections
    if "zero_drift" in sec.fits:
        c = sec.fits["zero_drift"]
        return c.value, c.lo, c.hi
    z = sec.zero
    half = 1.96 * math.sqrt(z.cov[1][1]) * 3600
    return z.drift_n_per_s * 3600, z.drift_n_per_s * 3600 - half, z.drift_n_per_s * 3600 + half


def _agree(a: tuple[float, float, float], b: tuple[float, float, float]) -> bool:
    """Two (value, lo, hi) estimates agree: their difference lies within the 95 % interval
    of a difference (half-widths added in quadrature). After the resume the two runs see
    different noise, so each estimate scatters about the truth on its own."""
    return abs(a[0] - b[0]) <= math.hypot((a[2] - a[1]) / 2, (b[2] - b[1]) / 2)


def _assert_agree(full: CalibrationResult, resumed: CalibrationResult, truth_n_per_h: float) -> None:
    """The resumed run has two sessions, its drift interval holds the truth, and its drift
    and model coefficients agree with the uninterrupted run's."""
    (sec,) = resumed.sections
    assert len(sec.zero.session_starts_s) == 1
    drift = _drift(resumed)
    assert drift[1] <= truth_n_per_h <= drift[2], drift
    assert _agree(_drift(full), drift), (_drift(full), drift)
    for name in MODEL:
        if name in full.sections[0].fits:
            a, b = full.sections[0].fits[name], sec.fits[name]
            assert _agree((a.value, a.lo, a.hi), (b.value, b.lo, b.hi)), (name, a, b)


def _drift_warnings(cal: CalibrationResult) -> list[str]:
    """The warnings about a drift of the sensor zero or of the tares."""
    return [w for w in cal.warnings if "drifts" in w or "tare drift" in w]


@pytest.mark.parametrize("seed, stop_after", [(2020, 203), (11, 120), (12, 300)])
def test_resumed_luo_sweep_fits_the_drift_of_the_uninterrupted_one(tmp_path, seed,
                                                                   stop_after, shipped_sweep,
                                                                   uninterrupted):
    """The tester's case: per-depth tares, the twin's offset starting over at the resume
    (one offset for both sessions made the drift -1.42 N/h, truth +0.6 N/h). Seed 2020 is
    the shipped protocol's own: its uninterrupted run is the session's sweep of it."""
    if seed == SHIPPED_LUO_SEED:
        with Store(shipped_sweep("luo2020-baseline"), read_only=True) as store:
            full = calibrate_run(store, store.resolve_run_id("last"))
        resumed = calibrate_run(*_sweep(tmp_path, LUO, seed, stop_after))
    else:
        full, resumed = _pair(tmp_path, LUO, seed, stop_after, uninterrupted)
    _assert_agree(full, resumed, PROFILES["can-bldc"].drift_n_per_h)


@pytest.mark.parametrize("seed, stop_after", [(21, 100), (22, 60), (23, 150)])
def test_resumed_esc_sweep_fits_the_drift_of_the_uninterrupted_one(tmp_path, seed,
                                                                   stop_after, uninterrupted):
    full, resumed = _pair(tmp_path, ESC, seed, stop_after, uninterrupted)
    _assert_agree(full, resumed, PROFILES["esc-1100-1900"].drift_n_per_h)


def test_resumed_stm32_sweep_finds_the_drift_with_its_dead_zones(tmp_path, uninterrupted):
    """No speed feedback: the zero comes from the dead zones and the tares, per session."""
    full, resumed = _pair(tmp_path, STM32, 31, 400, uninterrupted)
    _assert_agree(full, resumed, PROFILES["stm32-pwm"].drift_n_per_h)
    assert resumed.sections[0].curve.dead_zones == full.sections[0].curve.dead_zones


def test_the_drift_comes_out_right_when_the_resume_rezeroes(tmp_path, uninterrupted):
    """The twin's offset carries on; the tare at the start and the resume's tare read the
    zero at two times, so the design separates the drift from the law."""
    full, resumed = _pair(tmp_path, BLDC.format(drift=2.0, tare="per_depth"), 14, 80,
                          uninterrupted, True)
    _assert_agree(full, resumed, 2.0)
    assert resumed.sections[0].drift_design.startswith("estimated: ")


@pytest.mark.parametrize("continuing", [True, False])
def test_without_a_tare_the_one_way_sweep_fits_no_drift_resumed_or_not(tmp_path, continuing,
                                                                       uninterrupted):
    """Nothing re-zeroes and the sweep passes neutral once: no design separates a drift from
    the law (issue 47), so neither run fits one; the resumed run keeps an offset per session
    (the re-opened twin's offset may start over) and says why no drift was fitted."""
    full, resumed = _pair(tmp_path, BLDC.format(drift=2.0, tare="never"), 14, 80,
                          uninterrupted, continuing)
    for cal in (full, resumed):
        (sec,) = cal.sections
        assert sec.drift_design.startswith("not estimable: one pass"), sec.drift_design
        assert "zero_drift" not in sec.fits
        assert any(w.startswith("zero drift not estimable") for w in sec.warnings)
    assert len(resumed.sections[0].zero.session_starts_s) == 1


@pytest.mark.parametrize("text, seed, stop_after", [
    (BLDC.format(drift=0.0, tare="per_depth"), 15, 100),
    (BLDC.format(drift=0.0, tare="never"), 16, 40),
    (ESC.replace("  seed: 1500", "  seed: 1500\n  overrides: {drift_n_per_h: 0.0}"), 24, 120),
])
def test_no_drift_warning_for_a_resumed_run_of_a_twin_without_drift(tmp_path, text, seed,
                                                                    stop_after):
    store, run_id = _sweep(tmp_path, text, seed, stop_after)
    resumed = calibrate_run(store, run_id)
    assert _drift_warnings(resumed) == []
    value, lo, hi = _drift(resumed)
    assert lo <= 0.0 <= hi, (value, lo, hi)


def test_calibration_json_lists_the_sessions_offsets(tmp_path):
    store, run_id = _sweep(tmp_path, BLDC.format(drift=2.0, tare="per_depth"), 17, 50)
    out = tmp_path / "out"
    assert main(["calibrate", run_id, "--db", str(store.path), "--out", str(out)]) == 0
    (doc,) = out.rglob("calibration.json")
    zero = json.loads(doc.read_text())["depths"][0]["zero"]
    first, second = zero["sessions"]
    (resumed,) = [e for e in store.events(run_id) if e["kind"] == "resumed"]
    assert first == {"start_s": None, "offset_n": zero["offset_n"]}
    assert second["start_s"] == pytest.approx(resumed["t_s"]) and math.isfinite(second["offset_n"])


# -- the fits themselves --------------------------------------------------------------------
def _thrust_points(seed: int, jump_n: float) -> tuple[np.ndarray, ...]:
    """Speeds, thrusts and times of a two-direction sweep whose zero drifts at 0.6 N/h and
    jumps by `jump_n` at t = 1000 s (a resume that re-zeroed)."""
    rng = np.random.default_rng(seed)
    n = np.tile(np.linspace(-1800, 1800, 41), 2)
    t = np.arange(n.size) * 25.0
    zero = 0.6 / 3600 * t + np.where(t >= 1000, jump_n, 0.0)
    f = 1.9e-5 * np.abs(n) * n + zero + rng.normal(0, 0.02, n.size)
    return n, f, t


def test_one_session_fits_exactly_as_before():
    """Sessions that hold no points add nothing: the fit and its zero are unchanged."""
    n, f, t = _thrust_points(1, 0.0)
    masks = {"fwd": n > 20, "rev": n < -20}
    plain = fit_thrust_speed(n, f, np.full(n.size, 0.02), None, t, masks)
    late = fit_thrust_speed(n, f, np.full(n.size, 0.02), None, t, masks, sessions=(1e9,))
    assert plain.columns == late.columns and late.session_starts == ()
    assert np.array_equal(plain.fit.beta, late.fit.beta)
    assert np.array_equal(plain.fit.cov, late.fit.cov)
    assert plain.zero == late.zero


def test_a_session_offset_takes_up_the_jump_and_the_drift_stays_common():
    n, f, t = _thrust_points(2, -0.35)
    masks = {"fwd": n > 20, "rev": n < -20}
    fit = fit_thrust_speed(n, f, np.full(n.size, 0.02), None, t, masks, sessions=(990.0,))
    zero = fit.zero
    assert zero.session_starts_s == (990.0,)
    truth = 0.6 / 3600 * t + np.where(t >= 1000, -0.35, 0.0)
    assert np.max(np.abs(zero.at(t) - truth)) < 0.03
    assert np.all(zero.var_at(t) > 0)
    (drift,) = [c for c in fit.zero_coefficients() if c.name == "zero_drift"]
    assert drift.lo <= 0.6 <= drift.hi
    assert fit_thrust_speed(n, f, np.full(n.size, 0.02), None, t, masks).zero_coefficients()[
        1].value < 0  # one offset for both sessions: the jump passes for a falling drift


def test_single_session_zero_line_keeps_its_formula():
    line = ZeroLine(0.1, 1e-4, 50.0, "model fit", ((1e-4, 1e-7), (1e-7, 1e-9)))
    t = np.array([0.0, 50.0, 500.0])
    assert np.array_equal(line.at(t), 0.1 + 1e-4 * (t - 50.0))
    assert np.array_equal(line.var_at(t), np.maximum(1e-4 + 2e-7 * (t - 50) + 1e-9 * (t - 50) ** 2,
                                                     0.0))
