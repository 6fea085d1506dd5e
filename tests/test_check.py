"""`rigtool check` on a simulator rig file: rates, noise and feedback are reported."""

from __future__ import annotations

from rigtool.check import run_check
from rigtool.cli import main
from rigtool.rig import load_rig, open_rig

from .conftest import ROOT

RIG = ROOT / "protocols/rigs/sim-can-bldc.yaml"


def test_check_reports_rate_noise_and_feedback():
    rig, _ = load_rig(RIG)
    rigset = open_rig(rig, start_depth_m=1.0)
    report = run_check(rigset, seconds=1.0, rate_hz=500.0, command=50.0)
    assert report.samples == 500 and abs(report.rate_hz - 500.0) < 1.0
    names = [c.name for c in report.channels]
    assert names == ["fx", "fy", "fz", "tx", "ty", "tz"]
    speed = next(f for f in report.feedback if f.name == "speed_rpm")
    assert abs(speed.mean - 900.0) < 30.0  # 50 % of 1800 r/min, settled before measuring
    assert rigset.actuator.command == 0.0  # back at neutral


def test_check_cli_prints_table(capsys):
    assert main(["check", str(RIG), "--seconds", "0.5"]) == 0
    text = capsys.readouterr().out
    assert "force samples" in text and "speed_rpm" in text and "r/min" in text


def test_check_missing_rig_file_is_usage_error(capsys, tmp_path):
    assert main(["check", str(tmp_path / "rig.yaml")]) == 2
    assert "rig.yaml: file not found" in capsys.readouterr().err


def test_check_refuses_a_command_outside_the_range(capsys):
    assert main(["check", str(RIG), "--command", "1500"]) == 2
    assert "outside the actuator's range" in capsys.readouterr().err
