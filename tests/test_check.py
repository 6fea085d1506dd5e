"""`rigtool check` on a simulator rig file: rates, noise and feedback are reported."""

from __future__ import annotations

import time

import pytest
import yaml

from rigtool.check import run_check
from rigtool.cli import main
from rigtool.rig import Rig, load_rig, open_rig
from rigtool.sim.gauge_twin import GaugeTwin
from rigtool.sim.live import LiveTwin
from rigtool.sim.physics import ThrusterTwin
from rigtool.sim.stm32_twin import Stm32BridgeTwin
from rigtool.thruster_profiles import PROFILES

from .conftest import ROOT

RIG = ROOT / "protocols/rigs/sim-can-bldc.yaml"
SLOW_RIG = """\
rigtool_rig: 1
name: slow-gauge
actuator: {{driver: stm32-bridge, url: '{url}', timeout_s: 0.5}}
sensor: {{driver: ascii-gauge, url: '{port}', preset: hx711-csv, scale: 0.001, offset: 8000}}
"""


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


@pytest.mark.slow
def test_check_on_an_80hz_gauge_reads_for_the_seconds_asked(capsys):
    """Reads were sized for 1 kHz: `--seconds 3` on an 80 Hz gauge read for 38 s."""
    live = LiveTwin(ThrusterTwin(PROFILES["stm32-pwm"], seed=5)).start()
    bridge = Stm32BridgeTwin(live).start()
    gauge = GaugeTwin(live, "hx711-csv", rate_hz=80, scale=0.001, offset=8000).start()
    try:
        rig = Rig.model_validate(yaml.safe_load(SLOW_RIG.format(url=bridge.url, port=gauge.port)))
        rigset = open_rig(rig, start_depth_m=0.3)
        try:
            start = time.monotonic()
            report = run_check(rigset, seconds=2.0)
            took = time.monotonic() - start
        finally:
            rigset.close()
    finally:
        gauge.stop()
        bridge.stop()
        live.stop()
    assert 2.0 <= took < 6.0  # 0.5 s of rate probe, 2 s of reading, opening slack
    assert 1.7 <= report.seconds <= 2.3 and report.rate_hz == pytest.approx(80, rel=0.1)
