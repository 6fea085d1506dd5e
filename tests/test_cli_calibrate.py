"""End to end through the CLI: the stages `calibrate` and `report` choose from what a run
contains, the warnings they agree on, and the actuator neutral a run records."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from rigtool.analysis.dataset import load_run
from rigtool.cli import main
from rigtool.store import StepRecord, Store

from .conftest import PROTOCOLS

# stm32-pwm.yaml cut down: the dead zone, break-away and both plateaus, shallow, no feedback.
STM32_SMALL = """\
rigtool_protocol: 1
name: stm32-pwm-small
simulator: {profile: stm32-pwm, seed: 2017}
metadata: {thruster_id: stern-1}
command: {unit: pwm_counts, range: {start: 380, stop: 480, step: 1}, order: up}
depth: {unit: cm, values: [30], mode: preset}
timing: {settle: {seconds: 0.5}, acquire: {samples: 60, rate_hz: 250}, rest_s: 0.0,
         tare: per_depth}
limits: {max_thrust_n: 10}
"""
# One shallow point on the CAN twin: speed and current feedback.
CAN_SHALLOW = """\
rigtool_protocol: 1
name: can-shallow
simulator: {profile: can-bldc, seed: 4}
metadata: {thruster_id: bldc-350w}
command: {unit: percent, values: [60], order: up}
depth: {unit: cm, values: [30], mode: manual}
timing: {settle: {seconds: 1.0}, acquire: {seconds: 2, rate_hz: 250}, rest_s: 0.0,
         tare: per_depth}
limits: {max_thrust_n: 90, max_current_a: 12, max_speed_rpm: 2000, slew_per_s: 200}
"""


def _sweep(tmp: Path, text: str, name: str) -> str:
    path = tmp / f"{name}.yaml"
    path.write_text(text)
    assert main(["sweep", str(path), "--sim", "--db", str(tmp / "db.sqlite")]) == 0
    return Store(tmp / "db.sqlite").resolve_run_id("last")


def _cli(tmp: Path, *args: str) -> int:
    return main([*args, "--db", str(tmp / "db.sqlite"), "--out", str(tmp / "out")])


def _warnings(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.startswith("warning: ")]


def test_shallow_run_without_feedback_is_an_ordinary_calibration(tmp_path, capsys):
    run = _sweep(tmp_path, STM32_SMALL, "pwm")
    capsys.readouterr()
    assert _cli(tmp_path, "calibrate", "last") == 0
    calibrate_err = capsys.readouterr().err
    assert _cli(tmp_path, "report", "last") == 0
    report = capsys.readouterr()
    assert "quasi-cavitation" not in calibrate_err + report.err
    assert _warnings(calibrate_err) == _warnings(report.err)
    folder = tmp_path / "out" / run
    assert (folder / "calibration.json").exists() and not (folder / "cavitation.json").exists()
    html = (folder / "report.html").read_text()
    assert str(folder / "report.html") in report.out and 'id="cavitation"' not in html


def test_base_for_a_run_without_feedback_is_a_one_line_error(tmp_path, capsys):
    run = _sweep(tmp_path, STM32_SMALL, "pwm")
    capsys.readouterr()
    assert _cli(tmp_path, "calibrate", run, "--base", run) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith(f"rigtool: error: --base {run}: ")
    assert f"run {run} has no speed and current feedback" in err
    assert not (tmp_path / "out").exists()


def test_base_run_must_be_deep_with_speed_and_current(tmp_path, capsys):
    deep_pwm = _sweep(tmp_path, STM32_SMALL.replace("{unit: cm, values: [30]",
                                                    "{unit: m, values: [1.0]"), "deep-pwm")
    shallow = _sweep(tmp_path, CAN_SHALLOW, "shallow")
    capsys.readouterr()
    assert _cli(tmp_path, "calibrate", shallow, "--base", deep_pwm) == 2
    err = capsys.readouterr().err
    assert "not usable as a base run" in err and f"run {deep_pwm} has no speed and current" in err
    assert _cli(tmp_path, "calibrate", shallow, "--base", shallow) == 2
    assert f"run {shallow} is not deep" in capsys.readouterr().err


def test_shallow_run_without_base_warns_alike_in_calibrate_and_report(tmp_path, capsys):
    run = _sweep(tmp_path, CAN_SHALLOW, "shallow")
    capsys.readouterr()
    assert _cli(tmp_path, "calibrate", run) == 0
    calibrate_err = capsys.readouterr().err
    assert _cli(tmp_path, "report", run) == 0
    report_err = capsys.readouterr().err
    expected = f"warning: no quasi-cavitation section: no deep base run found for {run}"
    assert any(w.startswith(expected) for w in _warnings(calibrate_err))
    assert _warnings(calibrate_err) == _warnings(report_err)
    folder = tmp_path / "out" / run
    assert (folder / "calibration.json").exists() and not (folder / "cavitation.json").exists()
    html = (folder / "report.html").read_text()
    assert "No warnings" not in html and "no quasi-cavitation section" in html


def test_native_run_records_the_neutral_of_its_actuator(tmp_path):
    text = (PROTOCOLS / "quick-demo.yaml").read_text()
    text = text.replace("  seed: 7\n", "  seed: 7\n  overrides: {neutral: 20}\n")
    run = _sweep(tmp_path, text.replace("samples: 1000", "samples: 300"), "neutral")
    actuator = Store(tmp_path / "db.sqlite").run(run)["actuator"]
    assert actuator == {"command_unit": "percent", "neutral": 20.0, "command_min": -100.0,
                        "command_max": 100.0, "feedback": ["speed_rpm", "current_a", "voltage_v"]}
    assert _cli(tmp_path, "calibrate", "last") == 0
    doc = json.loads((tmp_path / "out" / run / "calibration.json").read_text())
    assert doc["source"]["neutral_command"] == 20.0


def test_run_without_an_actuator_record_keeps_its_protocol_neutral(db_path):
    store = Store(db_path)
    run = store.create_run(name="imported", protocol={"command": {"unit": "pulse_us", "neutral": 1490}},
                           protocol_path=None, rig={}, plan=[], metadata={}, seed=None,
                           command_unit="pulse_us", tool_version="t")
    step = StepRecord(idx=0, command=1600, command_unit="pulse_us", depth_m=1.0, repeat=0,
                      direction="up", t_start_s=0, t_acquire_s=0, t_end_s=1, settle_s=0,
                      settled=True, rate_hz=10)
    store.add_step(run, step, {"t_s": np.arange(5) * 0.1, "thrust_n": np.ones(5)})
    assert store.run(run)["actuator"] is None
    assert load_run(store, run).neutral_command == 1490.0
