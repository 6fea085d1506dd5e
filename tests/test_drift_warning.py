"""The drift warning: only for a drift whose 95 % interval excludes zero and that moves the
sensor zero by more than the thrust noise over the sweep; said in newtons over the sweep."""

from __future__ import annotations

import os
import re
import signal
from pathlib import Path

import numpy as np
import pytest

from rigtool.cli import main
from rigtool.progress import SilentReporter
from rigtool.report import figures as fg
from rigtool.store import Store
from rigtool.workflows import stored_results

pytestmark = pytest.mark.usefixtures("terminal_signals")  # sweeps stopped by Ctrl-C and resumed

TWIN = """\
rigtool_protocol: 1
name: drift-twin
simulator:
  profile: can-bldc
  seed: {seed}
  overrides: {{drift_n_per_h: {drift}}}
command: {{unit: percent, range: {{start: -90, stop: 90, step: 10}}, order: up-down}}
depth: {{unit: m, values: [1.0]}}
timing:
  settle: {{seconds: 1.0}}
  acquire: {{seconds: 2.0, rate_hz: 250}}
  rest_s: 2.0
  tare: {tare}
limits: {{max_thrust_n: 90, slew_per_s: 400}}
"""
MOVED = re.compile(r"([-+][\d.e-]+) N over the sweep \(\S+ min at (\S+) N/h")


def _drift_warnings(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.startswith("warning:") and "drift" in line]


def _twin_run(tmp: Path, drift: float, seed: int, tare: str = "at_start") -> str:
    """Sweep the CAN twin (its zero drifting `drift` N/h, force noise 0.12 N, about 4.5 min of
    points), calibrate it, and return what calibrate printed on stderr."""
    path = tmp / f"drift-{drift:g}-{seed}.yaml"
    path.write_text(TWIN.format(seed=seed, drift=drift, tare=tare))
    db = str(tmp / f"{path.stem}.sqlite")
    assert main(["sweep", str(path), "--sim", "--db", db]) == 0
    return db


@pytest.mark.parametrize("seed", [31, 32])
def test_twin_without_drift_gives_no_drift_warning(tmp_path, capsys, seed):
    db = _twin_run(tmp_path, 0.0, seed)
    capsys.readouterr()
    assert main(["calibrate", "last", "--db", db, "--out", str(tmp_path / "out")]) == 0
    assert _drift_warnings(capsys.readouterr().err) == []


def test_drift_that_moves_the_zero_less_than_the_noise_is_not_warned(tmp_path, capsys):
    """0.6 N/h (the profile's own) over 4.5 min moves the zero 0.045 N: noise is 0.12 N."""
    db = _twin_run(tmp_path, 0.6, 33)
    capsys.readouterr()
    assert main(["calibrate", "last", "--db", db, "--out", str(tmp_path / "out")]) == 0
    assert _drift_warnings(capsys.readouterr().err) == []


def test_drift_that_matters_is_warned_in_newtons_over_the_sweep(tmp_path, capsys):
    """6 N/h over 4.5 min moves the zero about 0.45 N, four times the 0.12 N noise."""
    db = _twin_run(tmp_path, 6.0, 34)
    capsys.readouterr()
    assert main(["calibrate", "last", "--db", db, "--out", str(tmp_path / "out")]) == 0
    (warning,) = _drift_warnings(capsys.readouterr().err)
    moved, rate = (float(x) for x in MOVED.search(warning).groups())
    assert rate == pytest.approx(6.0, rel=0.1)
    with Store(db) as store:
        steps = store.steps(store.resolve_run_id("last"))
    span_h = (steps[-1]["t_end_s"] - steps[0]["t_acquire_s"]) / 3600
    assert moved == pytest.approx(6.0 * span_h, rel=0.15)


def _stand_log(seed: int, drift_n_per_h: float) -> str:
    """A thrust-stand log (Tyto/RCbenchmark columns): an ESC thruster held 4 s at each command,
    a constant load-cell offset, plus `drift_n_per_h`."""
    rng = np.random.default_rng(seed)
    commands = np.repeat(np.arange(1100.0, 1901.0, 20.0), 80)
    t = np.arange(commands.size) / 20.0
    x = np.maximum(np.abs(commands - 1500) - 30, 0) / 370
    n = np.sign(commands - 1500) * 3500 * x
    f = np.where(n >= 0, 40.0, 32.0) * x**2 * np.sign(commands - 1500)
    read = f + 0.4 + drift_n_per_h * t / 3600 + rng.normal(0, 0.03 + 0.01 * np.abs(f))
    current = 0.2 + 18 * x**3 + rng.normal(0, 0.02, t.size)
    rows = ["Time (s),ESC signal (µs),Thrust (kgf),Voltage (V),Current (A),"
            "Motor Optical Speed (RPM)"]
    rows += [f"{a:.3f},{c:.0f},{b / 9.80665:.6f},16.000,{i:.4f},{abs(s):.1f}"
             for a, c, b, i, s in zip(t, commands, read, current, n, strict=True)]
    return "\n".join(rows) + "\n"


@pytest.mark.parametrize("seed, drift", [(101, 0.0), (102, 0.0), (103, 0.0), (104, 30.0)])
def test_a_one_way_import_fits_no_drift_and_says_why(tmp_path, capsys, seed, drift):
    """A one-way stand log (one pass 1100 -> 1900 us, neutral once, no tare) cannot separate a
    drift from the law (issue 47): no drift is fitted or warned of as measured, with or
    without a real one; one warning says so and that the zero is the neutral rows' mean."""
    log = tmp_path / f"stand-{seed}.csv"
    log.write_text(_stand_log(seed, drift))
    db = str(tmp_path / "db.sqlite")
    assert main(["import", str(log), "--db", db]) == 0
    capsys.readouterr()
    assert main(["calibrate", "last", "--db", db, "--out", str(tmp_path / "out")]) == 0
    (warning,) = _drift_warnings(capsys.readouterr().err)
    assert warning.startswith("warning: zero drift not estimable: one pass"), warning
    assert "the zero is the mean of the neutral rows" in warning
    assert MOVED.search(warning) is None


class CtrlCAfterPoint(SilentReporter):
    """Presses Ctrl-C once point `idx` is stored."""

    def __init__(self, idx: int) -> None:
        self.idx = idx

    def step_done(self, step, thrust_n) -> None:
        if step.idx == self.idx:
            os.kill(os.getpid(), signal.SIGINT)


def test_resumed_run_with_two_tares_has_no_nan_interval(tmp_path, capsys, monkeypatch):
    """Tared at the start and again at the resume: a trend but no interval, and no warning."""
    path = tmp_path / "two-tares.yaml"
    path.write_text(TWIN.format(seed=35, drift=30.0, tare="at_start"))
    db = str(tmp_path / "db.sqlite")
    monkeypatch.setattr("rigtool.cli.sweep.default_reporter", lambda: CtrlCAfterPoint(8))
    assert main(["sweep", str(path), "--sim", "--db", db]) == 130
    monkeypatch.setattr("rigtool.cli.sweep.default_reporter", SilentReporter)
    assert main(["sweep", "--resume", "last", "--db", db]) == 0
    capsys.readouterr()
    assert main(["calibrate", "last", "--db", db, "--out", str(tmp_path / "out")]) == 0
    err = capsys.readouterr().err
    assert not [w for w in _drift_warnings(err) if "tare drift" in w]
    with Store(db) as store:
        drift = stored_results(store, store.resolve_run_id("last")).calibration.drift
    assert drift.slope.n == 2
    fig = fg.tare_drift(drift)
    labels = fig.axes[0].get_legend_handles_labels()[1]
    assert not [label for label in labels if "nan" in label.lower()], labels
    assert any("2 tares: no interval" in label for label in labels)
