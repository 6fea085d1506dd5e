"""Runs never store data under a false label: sweeps through the CLI with the real drivers.

The VESC twin on a python-can virtual bus and the STM32 bridge twin on TCP drive the
LiveTwin; the Net F/T twin streams it over loopback UDP. Faults are switched on the twins
while the sweep runs: a drive that times out, a bridge that stops replying.
"""

from __future__ import annotations

import threading
import uuid
from collections.abc import Callable
from pathlib import Path

import pytest

from rigtool.cli import main
from rigtool.devices.depth import ManualDepth
from rigtool.engine import Engine
from rigtool.sim.live import LiveTwin
from rigtool.sim.netft_twin import NetFTTwin
from rigtool.sim.physics import ThrusterTwin
from rigtool.sim.stm32_twin import Stm32BridgeTwin
from rigtool.sim.vesc_twin import VescTwin
from rigtool.store import Store
from rigtool.sweep import open_checked, resolve
from rigtool.thruster_profiles import PROFILES

from .helpers import drain

VESC_TIMEOUT_S = 0.5  # the twin's command timeout (App Settings > Timeout)
SET_CURRENT = 1

CAN_PROTOCOL = """\
rigtool_protocol: 1
name: labels
command: {unit: percent, values: VALUES}
depth: {unit: m, values: DEPTHS}
timing:
  settle: {seconds: 1.5}
  acquire: {samples: 500, rate_hz: 1000}
  rest_s: 0.1
  tare: at_start
  tare_s: 0.2
limits: {max_thrust_n: 90, slew_per_s: 400}
"""


def protocol_text(values: list[float], depths: list[float] | None = None) -> str:
    return CAN_PROTOCOL.replace("VALUES", str(values)).replace("DEPTHS", str(depths or [1.0]))


@pytest.fixture
def channel() -> str:
    return f"labels-{uuid.uuid4().hex[:10]}"


@pytest.fixture
def vesc(live, channel):
    twin = VescTwin(live, channel=channel, timeout_s=VESC_TIMEOUT_S).start()
    yield twin
    twin.stop()


@pytest.fixture
def box(live):
    twin = NetFTTwin(live).start()
    yield twin
    twin.stop()


def netft_section(box: NetFTTwin) -> str:
    host, port = box.address
    return f"sensor: {{driver: ati-netft, host: {host}, port: {port}, http_port: {box.http_port}}}\n"


@pytest.fixture
def can_rig(write_yaml, vesc, box, channel):
    """Write a rig file reaching the VESC and Net F/T twins; `actuator` adds vesc-can fields."""

    def _write(actuator: str = "") -> Path:
        text = ("rigtool_rig: 1\nname: can-twins\nthrust: {channel: fx, sign: 1}\n"
                f"actuator: {{driver: vesc-can, interface: virtual, channel: {channel}, "
                f"bitrate: null{', ' + actuator if actuator else ''}}}\n" + netft_section(box))
        return write_yaml(text, "rig.yaml")

    return _write


def when(predicate: Callable[[], bool], action: Callable[[], None]) -> threading.Event:
    """Run `action` once `predicate` holds (polled on a thread); set the returned event to stop."""
    stop = threading.Event()

    def _watch() -> None:
        while not stop.wait(0.005):
            if predicate():
                action()
                return

    threading.Thread(target=_watch, daemon=True).start()
    return stop


def sweep(protocol: Path, rig: Path, db: Path) -> int:
    return main(["sweep", str(protocol), "--rig", str(rig), "--db", str(db)])


def follow_trip(store: Store, run_id: str) -> dict:
    (trip,) = store.events(run_id, "limit_trip")
    assert trip["detail"]["check"] == "follow", trip
    return trip["detail"]


@pytest.mark.slow
def test_keepalive_off_with_a_drive_timeout_trips_in_the_first_point(
        can_rig, vesc, live, write_yaml, db_path, capsys):
    """The rig file claims the VESC has no timeout; it has one: the motor stops mid-point."""
    rig = can_rig("keepalive_s: 0, command_timeout_s: 0")
    assert sweep(write_yaml(protocol_text([20, 40])), rig, db_path) == 1
    assert "not following the command" in capsys.readouterr().err
    store = Store(db_path)
    run_id = store.resolve_run_id("last")
    assert store.run(run_id)["status"] == "aborted" and store.steps(run_id) == []
    detail = follow_trip(store, run_id)
    assert detail["command"] == 20 and detail["held_s"] < 1.5  # within the settle of point 0
    assert detail["held_s"] - VESC_TIMEOUT_S < 1.0  # time from the drive stopping to the trip
    assert vesc.commands[-1] == (SET_CURRENT, 0.0) and live.command == 0.0


@pytest.mark.slow
def test_a_drive_that_times_out_mid_run_trips_within_the_point_and_ends_at_neutral(
        can_rig, vesc, live, recorder, write_yaml, db_path):
    """Keep-alive fine, but the VESC stops hearing the bus once point 1 holds 40 %."""
    rig = can_rig(f"command_timeout_s: {VESC_TIMEOUT_S}")
    stop = when(lambda: live.command == 40.0, lambda: setattr(vesc, "deaf", True))
    try:
        assert sweep(write_yaml(protocol_text([20, 40])), rig, db_path) == 1
    finally:
        stop.set()
    store = Store(db_path)
    run_id = store.resolve_run_id("last")
    assert [s["command"] for s in store.steps(run_id)] == [20]  # point 0 was followed
    detail = follow_trip(store, run_id)
    assert detail["command"] == 40 and detail["held_s"] < 2.0
    assert vesc.timed_out and live.command == 0.0  # its timeout stopped it
    ours = [m for m in drain(recorder) if m.arbitration_id >> 8 in (0, 1, 3)]
    assert ours[-1].arbitration_id >> 8 == SET_CURRENT and bytes(ours[-1].data) == bytes(4)


@pytest.mark.slow
def test_transport_counters_are_stored_per_point_and_shown(can_rig, vesc, write_yaml, db_path,
                                                           capsys):
    """rpm mode (the driver knows the speed its command gives), with garbage on the bus."""
    rig = can_rig("mode: rpm, command_unit: percent, max_erpm: 12600")
    vesc.garbage = True
    assert sweep(write_yaml(protocol_text([-40, 0, 40])), rig, db_path) == 0
    store = Store(db_path)
    run_id = store.resolve_run_id("last")
    speeds = [s["speed_all_mean_rpm"] for s in store.steps(run_id)]
    assert speeds[0] == pytest.approx(-720, abs=40) and speeds[2] == pytest.approx(720, abs=40)
    summary = store.transport_counters(run_id)
    assert summary["problem_points"] == [0, 1, 2]
    actuator, sensor = summary["totals"]["actuator"], summary["totals"]["sensor"]
    assert actuator["frames"] > 300 and actuator["garbage"] > 100 and actuator["error_frames"] > 50
    assert sensor["records"] >= 3 * 500 and sensor["lost_packets"] == 0
    (total,) = store.events(run_id, "transport_counters")
    assert total["detail"]["actuator"]["garbage"] >= actuator["garbage"]
    capsys.readouterr()
    assert main(["show", "last", "--db", str(db_path)]) == 0
    text = capsys.readouterr().out
    assert "transport counters over the stored points:" in text
    assert f"actuator: frames={actuator['frames']}, garbage={actuator['garbage']}" in text
    assert "points with lost, garbage or failed frames: 3 of 3 (points 0, 1, 2)" in text


def test_keepalive_off_against_the_drive_timeout_is_a_config_error(can_rig, write_yaml, db_path,
                                                                    capsys):
    rig = can_rig("keepalive_s: 0")
    assert sweep(write_yaml(protocol_text([20, 40])), rig, db_path) == 2
    err = capsys.readouterr().err
    assert f"{rig}:4: actuator.keepalive_s: " in err and "turns the keep-alive off" in err


def test_varying_depths_without_a_stage_are_a_config_error(can_rig, write_yaml, db_path, capsys):
    rig = can_rig()
    protocol = write_yaml(protocol_text([20], [0.3, 0.5]))
    assert sweep(protocol, rig, db_path) == 2
    err = capsys.readouterr().err
    assert f"{protocol}:4: depth.mode: 'preset' means one fixed depth" in err
    assert "mode: manual" in err


@pytest.mark.slow
def test_manual_depths_are_recorded_as_the_operator_reported_them(can_rig, write_yaml, db_path):
    text = protocol_text([20], [0.3, 0.5]).replace("values: [0.3, 0.5]}",
                                                   "values: [0.3, 0.5], mode: manual}")
    setup = resolve(write_yaml(text), can_rig())
    rigset = open_checked(setup)
    answers = iter(["", "52"])  # Enter: at the depth asked for; or the depth reached, in cm
    rigset.depth_stage = ManualDepth(ask=lambda question: next(answers), interactive=True)
    store = Store(db_path)
    run_id = store.create_run(name="t", protocol={}, protocol_path=None, rig={}, plan=[],
                              metadata={}, seed=None, command_unit="percent", tool_version="test")
    try:
        assert Engine(setup.protocol, setup.plan, rigset, store, run_id).run().status == "completed"
    finally:
        rigset.close()
    depths = [e["detail"] for e in store.events(run_id, "depth")]
    assert depths == [{"target_m": 0.3, "reached_m": 0.3, "by": "operator"},
                      {"target_m": 0.5, "reached_m": 0.52, "by": "operator"}]


BRIDGE_PROTOCOL = """\
rigtool_protocol: 1
name: bridge
command: {unit: pwm_counts, values: [0, 300]}
depth: {unit: cm, values: [30]}
timing:
  settle: {seconds: 0.5}
  acquire: {samples: 300, rate_hz: 1000}
  tare: at_start
  tare_s: 0.2
limits: {max_thrust_n: 20}
"""


@pytest.mark.slow
def test_a_bridge_that_stops_replying_is_not_reported_at_neutral(write_yaml, db_path, capsys):
    live = LiveTwin(ThrusterTwin(PROFILES["stm32-pwm"], seed=1)).start()
    fw = Stm32BridgeTwin(live).start()
    box = NetFTTwin(live).start()
    stop = when(lambda: live.command == 300, lambda: setattr(fw, "no_replies", True))
    try:
        rig = write_yaml("rigtool_rig: 1\nname: bridge\nthrust: {channel: fz, sign: -1}\n"
                         f"actuator: {{driver: stm32-bridge, url: '{fw.url}', timeout_s: 0.2}}\n"
                         + netft_section(box), "rig.yaml")
        assert sweep(write_yaml(BRIDGE_PROTOCOL), rig, db_path) == 3  # not at neutral
    finally:
        stop.set()
        for part in (box, fw, live):
            part.stop()
    err = capsys.readouterr().err
    assert "THE NEUTRAL COMMAND FAILED" in err and "actuator at neutral" not in err
    store = Store(db_path)
    run_id = store.resolve_run_id("last")
    assert store.events(run_id, "device_fault") and store.events(run_id, "neutral_failed")
    assert [s["command"] for s in store.steps(run_id)] == [0]
