"""Rig files: every shipped example validates as a whole rig; bad combinations are refused."""

from __future__ import annotations

import pytest

from rigtool.errors import ConfigError
from rigtool.rig import load_rig

from .conftest import ROOT

RIGS = sorted((ROOT / "protocols/rigs").glob("*.yaml"))


@pytest.mark.parametrize("path", RIGS, ids=lambda p: p.stem)
def test_shipped_rig_files_validate(path):
    rig, _ = load_rig(path)
    assert rig.simulator is not None or (rig.actuator is not None and rig.sensor is not None)


def _load(write_yaml, text):
    with pytest.raises(ConfigError) as info:
        load_rig(write_yaml(text, "rig.yaml"))
    return str(info.value)


def test_hardware_rig_needs_actuator_and_sensor(write_yaml):
    msg = _load(write_yaml, "name: r\nsensor: {driver: ati-netft, host: 10.0.0.1}\n")
    assert "needs both an `actuator:` and a `sensor:`" in msg


def test_unknown_driver_lists_the_known_ones(write_yaml):
    msg = _load(write_yaml, "name: r\nactuator: {driver: teleporter, url: x}\nsensor: {driver: ati-netft, host: h}\n")
    assert "rig.yaml:2: actuator" in msg and "stm32-bridge" in msg and "vesc-can" in msg


def test_driver_field_errors_have_lines(write_yaml):
    text = ("name: r\nactuator:\n  driver: stm32-bridge\n  url: /dev/ttyACM0\n  arr: -5\n"
            "sensor: {driver: ati-netft, host: h}\n")
    msg = _load(write_yaml, text)
    assert "rig.yaml:5: actuator.arr" in msg


def test_mount_with_single_axis_gauge_is_refused(write_yaml):
    text = ("name: r\nactuator: {driver: stm32-bridge, url: loop://}\n"
            "sensor: {driver: ascii-gauge, url: /dev/ttyUSB0, preset: mark10}\nmount: {rotation_deg: 90}\n")
    assert "single-axis gauge" in _load(write_yaml, text)


def test_simulator_and_hardware_are_exclusive(write_yaml):
    text = "name: r\nsimulator: {profile: can-bldc}\nsensor: {driver: ati-netft, host: h}\n"
    assert "not both" in _load(write_yaml, text)


def test_relative_dbc_path_is_taken_from_the_rig_folder(write_yaml, tmp_path):
    (tmp_path / "my.dbc").write_text('VERSION ""\n\nBU_: HOST SERVO\n\n'
                                     'BO_ 512 Control: 2 HOST\n'
                                     ' SG_ Speed : 0|16@1- (1,0) [-3000|3000] "rpm" SERVO\n')
    text = ("name: r\nactuator:\n  driver: dbc-can\n  interface: virtual\n  channel: x\n"
            "  dbc: my.dbc\n  command: {message: Control, signal: Speed, unit: rpm}\n"
            "sensor: {driver: ati-netft, host: h}\n")
    rig, _ = load_rig(write_yaml(text, "rig.yaml"))  # the DBC is read (and checked) here
    assert rig.actuator.dbc == str(tmp_path / "my.dbc")
