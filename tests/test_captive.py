"""Captive runs: the protocol's `captive:` axis, the carriage (driver against its twin on a
real transport), the carriage stopped on every exit path, and the damping laws recovered
from the twin with their intervals, or refused with the reason."""

from __future__ import annotations

import json
import os
import signal
from pathlib import Path

import numpy as np
import pytest

from rigtool.analysis.captive import fit_captive
from rigtool.analysis.dataset import load_captive
from rigtool.cli import main
from rigtool.devices.serial_carriage import SerialCarriage, SerialCarriageConfig
from rigtool.engine import Engine
from rigtool.errors import ConfigError, DeviceError, SafetyTrip, UsageError
from rigtool.plan import expand, step_at
from rigtool.sim.carriage_twin import CarriageTwin
from rigtool.sim.vehicle_params import BLUEROV2, BLUEROV2_HEAVY
from rigtool.store import Store
from rigtool.sweep import open_checked, resolve

from .helpers import wait_for

CAPTIVE = """\
rigtool_protocol: 1
name: captive-test
simulator: {{profile: esc-1100-1900, seed: {seed}, vehicle: {vehicle}, flow_noise_frac: {noise}}}
captive:
  speeds_mps: {speeds}
  angles_deg: {angles}
  angle: {angle}
  settle_s: 1.0
command: {{unit: pulse_us, values: [1500]}}
depth: {{unit: m, values: [0.5]}}
timing:
  settle: {{seconds: 0.5}}
  acquire: {{seconds: 4, rate_hz: 100}}
  tare: at_start
{extra}"""
SPEEDS = "[-0.8, -0.55, -0.3, 0.3, 0.55, 0.8]"


def captive_text(*, seed: int = 5, vehicle: str = "bluerov2", noise: float = 0.03,
                 speeds: str = SPEEDS, angles: str = "[0, 45, 90]", angle: str = "yaw",
                 extra: str = "") -> str:
    """A small captive protocol for the twin."""
    return CAPTIVE.format(seed=seed, vehicle=vehicle, noise=noise, speeds=speeds,
                          angles=angles, angle=angle, extra=extra)


# -- the protocol --------------------------------------------------------------------------

def test_plan_visits_every_speed_at_every_angle_and_step_at_agrees(write_yaml):
    setup = resolve(write_yaml(captive_text(extra="limits: {max_thrust_n: 500}\n")), sim=True)
    plan = expand(setup.protocol)
    assert len(plan) == setup.protocol.n_points() == 18
    assert [(s.speed_mps, s.angle_deg) for s in plan[:7]] == [
        (-0.8, 0), (-0.55, 0), (-0.3, 0), (0.3, 0), (0.55, 0), (0.8, 0), (-0.8, 45)]
    assert all(step_at(setup.protocol, s.idx) == s for s in plan)
    assert "speed_mps" in plan[0].as_dict()


@pytest.mark.parametrize("speeds, angles, angle, field, words", [
    ("[-0.5, true]", "[0]", "yaw", "captive.speeds_mps.1", "valid number"),
    ("[-0.5, '0.5']", "[0]", "yaw", "captive.speeds_mps.1", "valid number"),
    ("[-0.5, 25]", "[0]", "yaw", "captive.speeds_mps.1", "less than or equal to 20"),
    ("[-0.5, 0.5, 0.5]", "[0]", "yaw", "captive.speeds_mps", "listed twice"),
    ("[-0.5, 0.5]", "[0, 200]", "yaw", "captive.angles_deg.1", "less than or equal to 180"),
    ("[-0.5, 0.5]", "[0]", "roll", "captive.angle", "'yaw' or 'attack'"),
])
def test_bad_captive_axes_name_file_line_and_field(write_yaml, speeds, angles, angle, field,
                                                   words):
    path = write_yaml(captive_text(speeds=speeds, angles=angles, angle=angle))
    with pytest.raises(ConfigError) as info:
        resolve(path, sim=True)
    text = str(info.value)
    assert f"{path}:" in text and f"{field}:" in text and words in text, text
    assert info.value.exit_status == 2


def test_unknown_captive_field_and_step_responses_are_refused(write_yaml, capsys):
    path = write_yaml(captive_text().replace("  angle: yaw\n", "  angle: yaw\n  axes: six\n"))
    assert main(["sweep", str(path), "--sim", "--dry-run"]) == 2
    assert f"{path}:8: captive.axes: unknown field" in capsys.readouterr().err
    steps = captive_text().replace("values: [1500]", "steps: [1500, 1600]").replace(
        "settle: {seconds: 0.5}", "settle: {seconds: 0}")
    with pytest.raises(ConfigError, match=r"captive: Value error, a captive run holds each "):
        resolve(write_yaml(steps), sim=True)


def test_a_hardware_rig_needs_a_carriage_within_its_limits(write_yaml, tmp_path):
    rig = tmp_path / "rig.yaml"
    base = ("rigtool_rig: 1\nname: bench\nactuator: {driver: vesc-can, interface: virtual, "
            "channel: c0, mode: duty}\nsensor: {driver: ati-netft, host: 127.0.0.1}\n")
    rig.write_text(base)
    path = write_yaml(captive_text())
    with pytest.raises(ConfigError, match=r"protocol.yaml:\d+: captive.mode: 'preset' needs a "
                                          r"`carriage:` section"):
        open_checked(resolve(path, rig_path=str(rig)))
    rig.write_text(base + "carriage: {driver: serial-carriage, url: 'loop://', "
                          "max_speed_mps: 0.5}\n")
    with pytest.raises(ConfigError, match=r"captive.speeds_mps: 0.8 m/s is beyond the "
                                          r"carriage's max_speed_mps \(0.5 m/s\)"):
        open_checked(resolve(path, rig_path=str(rig)))


def test_dry_run_opens_no_device(write_yaml, monkeypatch, capsys):
    def refuse(*args, **kwargs):
        raise AssertionError("a dry run opened a device")

    monkeypatch.setattr("rigtool.sweep.open_rig", refuse)
    monkeypatch.setattr("rigtool.sim.devices.SimCarriage.__init__", refuse)
    assert main(["sweep", str(write_yaml(captive_text())), "--sim", "--dry-run"]) == 0
    assert "captive flow: -0.8, -0.55" in capsys.readouterr().out


# -- the driver against its twin -----------------------------------------------------------

@pytest.mark.parametrize("transport", ["pty", "tcp"])
def test_driver_sets_flow_and_stops_over_a_real_transport(transport):
    with CarriageTwin(accel_mps2=4.0, turn_deg_s=180.0, seed=1) as twin:
        url = twin.pty_path if transport == "pty" else twin.url
        cfg = SerialCarriageConfig(driver="serial-carriage", url=url, accel_mps2=4.0,
                                   turn_deg_s=180.0, timeout_s=1.0)
        with SerialCarriage(cfg) as carriage:
            assert carriage.set_flow(0.6, 0.0) == (0.6, 0.0)
            assert twin.speed_mps == 0.6
            assert carriage.set_flow(-0.4, 30.0) == (-0.4, 30.0)  # stopped, turned, reversed
            assert ("FLOW", -0.4, 30.0) in twin.history
            assert carriage.state() == (-0.4, 30.0)
            with pytest.raises(UsageError, match="beyond the soft limit 2 m/s"):
                carriage.set_flow(2.5, 0.0)
            with pytest.raises(UsageError, match="outside the soft limits"):
                carriage.set_flow(0.5, 120.0)
        assert twin.speed_mps == 0.0  # closing stops it
        with pytest.raises(DeviceError, match="is closed"):
            carriage.state()


def test_driver_counts_garbage_reports_refusals_and_the_twin_watchdog_stops():
    with CarriageTwin(accel_mps2=4.0, max_speed_mps=1.0, watchdog_s=0.3, seed=2) as twin:
        twin.garbage = True
        cfg = SerialCarriageConfig(driver="serial-carriage", url=twin.pty_path, accel_mps2=4.0,
                                   max_speed_mps=1.5, timeout_s=1.0)
        carriage = SerialCarriage(cfg)
        try:
            with pytest.raises(DeviceError, match=r"refused .*speed beyond 1 m/s"):
                carriage.set_flow(1.2, 0.0)
            carriage.set_flow(0.5, 0.0)
            assert carriage.stats["garbage"] > 0
            twin.garbage = False
            assert wait_for(lambda: twin.speed_mps == 0.0, timeout_s=3.0)  # host went silent
            assert twin.watchdog_trips == 1
            twin.stalled = True
            with pytest.raises(DeviceError, match="no DONE reply"):
                carriage.set_flow(0.2, 0.0)
        finally:
            twin.stalled = False
            carriage.close()
        assert wait_for(lambda: twin.speed_mps == 0.0)


# -- the carriage stopped on every exit path ----------------------------------------------

class FaultySensor:
    """Wraps the twin's sensor; on read number `at` it runs `action` (raise, or a signal)."""

    def __init__(self, inner, at: int, action):
        self.inner, self.at, self.action, self.reads = inner, at, action, 0
        self.channels = inner.channels

    def read(self, n, rate_hz):
        self.reads += 1
        if self.reads == self.at:
            self.action()
        return self.inner.read(n, rate_hz)

    def set_bias(self, bias):
        self.inner.set_bias(bias)

    def close(self):
        self.inner.close()


def _raise(exc: BaseException):
    def action():
        raise exc
    return action


def _stale():  # the sensor's clock stops: its newest sample grows old
    raise SafetyTrip("sensor stale: newest sample is 2.00 s old (limit 1 s)")


@pytest.mark.parametrize("action, status", [
    (None, "completed"),
    (_raise(RuntimeError("bug")), "failed"),
    (_raise(KeyboardInterrupt()), "aborted"),
    (lambda: os.kill(os.getpid(), signal.SIGTERM), "aborted"),
    (_raise(DeviceError("Net F/T went silent")), "aborted"),
    (_stale, "aborted"),
], ids=["end", "exception", "ctrl-c", "sigterm", "lost-sensor", "stale-sensor"])
def test_carriage_ends_at_speed_zero(write_yaml, db_path, action, status):
    setup = resolve(write_yaml(captive_text()), sim=True)
    rigset = open_checked(setup)
    flow = rigset.world.flow
    if action is not None:
        rigset.sensor = FaultySensor(rigset.sensor, at=60, action=action)
    store = Store(db_path)
    run_id = store.create_run(name="t", protocol={}, protocol_path=None, rig={}, plan=[],
                              metadata={}, seed=1, command_unit="pulse_us", tool_version="test")
    engine = Engine(setup.protocol, setup.plan, rigset, store, run_id)
    try:
        engine.run()
    except RuntimeError:
        assert status == "failed"
    assert store.run(run_id)["status"] == status
    assert max(abs(v) for v in setup.protocol.captive.speeds_mps) > 0
    assert flow.target_mps == 0.0 and abs(float(flow.speed_at(rigset.clock.now()))) < 1e-4
    rigset.close()


def test_a_limit_trip_stops_the_carriage(write_yaml, db_path):
    setup = resolve(write_yaml(captive_text(extra="limits: {max_thrust_n: 8}\n")), sim=True)
    rigset = open_checked(setup)
    store = Store(db_path)
    run_id = store.create_run(name="t", protocol={}, protocol_path=None, rig={}, plan=[],
                              metadata={}, seed=1, command_unit="pulse_us", tool_version="test")
    outcome = Engine(setup.protocol, setup.plan, rigset, store, run_id).run()
    assert outcome.status == "aborted" and "thrust" in outcome.reason
    assert [e["kind"] for e in store.events(run_id, "limit_trip")] == ["limit_trip"]
    assert rigset.world.flow.target_mps == 0.0
    rigset.close()


# -- the laws --------------------------------------------------------------------------------

def _calibrated(tmp_path: Path, text: str, monkeypatch) -> dict:
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("RIGTOOL_DB", str(tmp_path / "rigtool.sqlite"))
    protocol = tmp_path / "captive.yaml"
    protocol.write_text(text)
    assert main(["sweep", str(protocol), "--sim"]) == 0
    assert main(["calibrate", "last"]) == 0
    assert main(["report", "last"]) == 0
    folder = next((tmp_path / "calibrations").iterdir())
    return json.loads((folder / "calibration.json").read_text()) | {"_folder": folder}


# seeds never used while the twin, the protocol or the fits were being written
@pytest.mark.parametrize("vehicle, truth, seed, angle", [
    ("bluerov2", BLUEROV2, 9101, "yaw"),
    ("bluerov2-heavy", BLUEROV2_HEAVY, 9102, "attack"),
])
def test_damping_recovered_within_3_percent_with_covering_intervals(
        tmp_path, monkeypatch, capsys, vehicle, truth, seed, angle):
    doc = _calibrated(tmp_path, captive_text(seed=seed, vehicle=vehicle, angle=angle),
                      monkeypatch)["captive"]
    across = 1 if angle == "yaw" else 2
    for k in (0, across):
        law = doc["laws"]["XYZ"[k]]
        scale = abs(truth.quadratic_damping[k])  # a zero truth is judged against the law's size
        for key, want in (("linear", truth.linear_damping[k]),
                          ("quadratic", truth.quadratic_damping[k])):
            got = law[key]
            assert abs(got["value"] - want) <= 0.03 * (abs(want) or scale), (law, want)
            assert got["lo"] <= want <= got["hi"], (key, got, want)
    refused = doc["laws"]["Z" if angle == "yaw" else "Y"]
    assert refused["linear"] is None and "never had this component" in refused["refused"]


def test_one_sign_of_flow_is_refused_with_its_reason(tmp_path, monkeypatch, capsys):
    doc = _calibrated(tmp_path, captive_text(speeds="[0.2, 0.4, 0.6, 0.8]", angles="[0, 30]"),
                      monkeypatch)
    law = doc["captive"]["laws"]["X"]
    assert law["linear"] is None and law["quadratic"] is None
    assert law["refused"] == "X_u and X_uu cannot be told apart: the flow never reversed"
    assert f"captive: {law['refused']}" in doc["warnings"]
    assert law["refused"] in capsys.readouterr().err
    report = (doc["_folder"] / "report.html").read_text()
    assert 'id="captive"' in report and "the flow never reversed" in report


def test_one_magnitude_is_refused_and_fits_read_back_from_the_store(tmp_path, monkeypatch):
    doc = _calibrated(tmp_path, captive_text(speeds="[-0.5, 0.5]", angles="[0]"), monkeypatch)
    assert "one speed magnitude" in doc["captive"]["laws"]["X"]["refused"]
    with Store(tmp_path / "rigtool.sqlite") as store:
        data = load_captive(store, store.resolve_run_id("last"))
    result = fit_captive(data)
    assert np.allclose(sorted(set(result.points.speed_mps)), [-0.5, 0.5], atol=1e-4)
    assert result.laws[0].linear is None


def test_crafted_captive_results_are_refused_on_read_back(tmp_path, monkeypatch):
    import dataclasses

    from rigtool.workflows import _inconsistency, stored_results

    _calibrated(tmp_path, captive_text(angles="[0]"), monkeypatch)
    with Store(tmp_path / "rigtool.sqlite") as store:
        cal = stored_results(store, store.resolve_run_id("last")).calibration
    assert _inconsistency(cal) is None
    points = dataclasses.replace(cal.captive.points, mean=cal.captive.points.mean[:, :5])
    bad = dataclasses.replace(cal, captive=dataclasses.replace(cal.captive, points=points))
    assert "captive.points.mean is not a" in _inconsistency(bad)
    bad = dataclasses.replace(cal, captive=dataclasses.replace(cal.captive, angle="roll"))
    assert _inconsistency(bad) == "captive.angle is 'roll'"


def test_a_carriage_that_cannot_stop_is_exit_status_3(write_yaml, db_path):
    setup = resolve(write_yaml(captive_text(angles="[0]")), sim=True)
    rigset = open_checked(setup)
    inner = rigset.carriage

    class Stuck:
        reached_by = inner.reached_by
        set_flow = inner.set_flow

        def stop(self):
            raise DeviceError("carriage controller not answering")

        def close(self):
            inner.close()

    rigset.carriage = Stuck()
    store = Store(db_path)
    run_id = store.create_run(name="t", protocol={}, protocol_path=None, rig={}, plan=[],
                              metadata={}, seed=1, command_unit="pulse_us", tool_version="test")
    outcome = Engine(setup.protocol, setup.plan, rigset, store, run_id).run()
    assert outcome.exit_status == 3 and "CARRIAGE MAY STILL BE MOVING" in outcome.neutral_note
    kinds = [e["kind"] for e in store.events(run_id)]
    assert "carriage_unsafe" in kinds and "neutral_failed" in kinds
    rigset.close()
