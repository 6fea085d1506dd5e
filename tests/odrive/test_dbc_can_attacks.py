"""Findings of an attack on the dbc-can driver, each over a real transport: the ODrive twin
on a python-can virtual bus, and rig files loaded as the CLI loads them.

A DBC id that already holds node bits under `node_id_shift` (S3), a rig command range
beyond the DBC signal's (W2), a silent heartbeat (S5), non-finite feedback (S6) and an
axis that leaves closed loop without an error (W1) must each stop or refuse, never pass.
"""

from __future__ import annotations

import time

import pytest
import yaml
from pydantic import ValidationError

from rigtool.cli import main
from rigtool.devices.dbc_can import DbcCanConfig, DbcCanDriver, DbcMismatch
from rigtool.errors import ConfigError, DeviceError, UsageError
from rigtool.rig import load_rig
from rigtool.sim.odrive_twin import CLOSED_LOOP_CONTROL, IDLE

from ..conftest import ROOT
from ..helpers import drain, wait_for
from .conftest import NODE

PROTOCOL = """\
rigtool_protocol: 1
name: odrive-attack
metadata: {thruster_id: odrive-bldc, propeller_diameter_m: 0.2, water_density_kg_m3: 1000}
command: {unit: rpm, values: [-1500, 0, 1500]}
depth: {unit: m, values: [1.0]}
timing:
  settle: {seconds: 1.0}
  acquire: {samples: 400, rate_hz: 1000}
  rest_s: 0.0
  tare: at_start
  tare_s: 0.2
limits: {max_thrust_n: 90, max_speed_rpm: 2000, slew_per_s: 3000}
"""


def odrive_rig(write_yaml, channel: str, **actuator) -> str:
    data = yaml.safe_load((ROOT / "protocols/rigs/odrive-example.yaml").read_text())
    data["actuator"].update(interface="virtual", channel=channel, bitrate=None, **actuator)
    return write_yaml(yaml.safe_dump(data, sort_keys=False), "rig.yaml")


# ----- S3: a DBC id with node bits under the shift would drive another node -----

def test_an_axis3_message_with_node_id_3_is_refused_at_rig_load(write_yaml, channel, recorder,
                                                                tmp_path):
    rig = odrive_rig(write_yaml, channel, node_id=NODE, command={
        "message": "Axis3_Set_Input_Vel", "signal": "Input_Vel", "unit": "rpm",
        "scale": 1 / 60, "min": -3000, "max": 3000})
    line = next(i for i, text in enumerate(rig.read_text().splitlines(), 1)
                if "Axis3_Set_Input_Vel" in text)
    with pytest.raises(ConfigError, match=rf"rig.yaml:{line}: actuator.command.message: "
                       r"Axis3_Set_Input_Vel has DBC id 0x6d, which already holds node 3"):
        load_rig(rig)
    protocol = write_yaml(PROTOCOL)
    assert main(["sweep", str(protocol), "--rig", str(rig), "--db",
                 str(tmp_path / "r.sqlite")]) == 2
    assert drain(recorder, 0.1) == []  # nothing sent to node 6 (0xcd) or anywhere


def test_node_bits_are_refused_for_feedback_messages_too(channel):
    cfg = DbcCanConfig(driver="dbc-can", interface="virtual", channel=channel,
                       mapping="odrive_velocity", node_id=0, feedback={"speed_rpm": {
                           "message": "Axis1_Get_Encoder_Estimates", "signal": "Vel_Estimate"}})
    with pytest.raises(DbcMismatch, match="Axis1_Get_Encoder_Estimates has DBC id 0x29") as exc:
        DbcCanDriver(cfg)
    assert exc.value.loc == ("feedback", "speed_rpm", "message")


def test_node_id_64_names_the_line_and_the_node_range(write_yaml, channel):
    rig = odrive_rig(write_yaml, channel, node_id=64)
    with pytest.raises(ConfigError, match=r"rig.yaml:\d+: actuator.node_id: node_id 64 puts "
                       r".*beyond the 11-bit range \(node_id 0..63 with node_id_shift 5\)"):
        load_rig(rig)


# ----- W2: a rig range beyond the DBC signal's would be clipped silently -----

def test_a_command_range_beyond_the_dbc_signal_is_refused_at_rig_load(write_yaml, channel):
    text = ("name: clip\nactuator:\n  driver: dbc-can\n  interface: virtual\n"
            f"  channel: {channel}\n  command:\n    message: SERVO_CONTROL\n"
            "    signal: SpeedCmd_rpm\n    unit: rpm\n    min: -2000\n    max: 5000\n"
            "sensor: {driver: ati-netft, host: 127.0.0.1}\n")  # fmt: skip
    with pytest.raises(ConfigError, match=r"rig.yaml:11: actuator.command.max: 5000 rpm is beyond "
                       r"the range of SERVO_CONTROL.SpeedCmd_rpm in the DBC: \[-3000, 3000\] rpm"):
        load_rig(write_yaml(text, "rig.yaml"))


# ----- S5: heartbeat silence is a fault even while other frames come -----

def test_a_silent_heartbeat_stops_the_run_while_encoder_frames_go_on(twin, open_driver):
    driver = open_driver()
    driver.set_command(600.0)
    frames = driver.stats["frames"]
    twin.no_heartbeat = True
    twin.fault_code = 0x40  # the axis faults to IDLE; only the heartbeat would have said so

    def silence() -> bool:
        try:
            driver.read_feedback()
        except DeviceError as exc:
            return "no Axis0_Heartbeat frames from odrive-cansimple node 3" in str(exc)
        return False

    assert wait_for(silence, 2.0)
    assert driver.stats["frames"] > frames + 20  # encoder frames went on all the while


# ----- S6: non-finite feedback is garbage and stops the run by its silence -----

@pytest.mark.parametrize("value", [float("nan"), float("inf")])
def test_non_finite_speed_feedback_is_garbage_and_stops_the_run(twin, open_driver, value):
    driver = open_driver()
    driver.set_command(600.0)
    driver.read_feedback()
    twin.vel_estimate = value
    garbage = driver.stats["garbage"]
    with pytest.raises(DeviceError, match=r"no Axis0_Get_Encoder_Estimates frames .* for 0.5 s "
                       rf"\(only non-finite values, e.g. Vel_Estimate={value}, counted as garbage"):
        assert wait_for(lambda: driver.read_feedback() and False, 2.0)
    assert driver.stats["garbage"] > garbage + 10


def test_non_finite_samples_never_reach_the_engine(twin, open_driver):
    driver = open_driver()
    twin.vel_estimate = float("nan")
    assert wait_for(lambda: driver.stats["garbage"] > 3, 1.0)
    driver.read_feedback()  # what came before the switch
    garbage = driver.stats["garbage"]
    assert wait_for(lambda: driver.stats["garbage"] > garbage + 5, 1.0)
    assert len(driver.read_feedback()) == 0


# ----- W1: an axis that leaves closed loop without an error is a fault -----

def test_an_axis_that_drops_to_idle_without_an_error_stops_the_run(twin, live, open_driver):
    driver = open_driver()
    driver.set_command(600.0)
    twin._request_state(IDLE)  # what a brown-out or an odrivetool user does: no Axis_Error
    assert twin.axis_error == 0 and twin.axis_state == IDLE
    assert wait_for(lambda: driver.fault is not None, 1.0)
    with pytest.raises(DeviceError, match=r"node 3 .*reports fault Axis_State=1 \(IDLE\), "
                                          r"expected Axis_State=8 \(CLOSED_LOOP_CONTROL\)"):
        driver.read_feedback()


def test_an_axis_that_cannot_enter_closed_loop_fails_the_open(twin, open_driver):
    twin.fault_code = 0x40  # closed loop is refused while an error is set
    with pytest.raises(DeviceError, match=r"did not reach Axis_State=8 \(CLOSED_LOOP_CONTROL\) "
                                          r"within 0.5 s of opening \(read Axis_State=1 \(IDLE\)\)"):
        open_driver()
    assert CLOSED_LOOP_CONTROL in twin.requested_states


# ----- cosmetic -----

@pytest.mark.parametrize("node_id", [True, "5", 5.0])
def test_node_id_is_a_strict_int(node_id):
    with pytest.raises(ValidationError, match="node_id"):
        DbcCanConfig(driver="dbc-can", channel="x", mapping="odrive_velocity", node_id=node_id)


def test_a_file_that_is_not_a_dbc_is_not_echoed(tmp_path):
    secret = tmp_path / "passwd"
    secret.write_text("s3cr3t:x:0:0:/s3cr3t:/bin/bash\n")
    cfg = DbcCanConfig(driver="dbc-can", channel="x", dbc=str(secret),
                       command={"message": "M", "signal": "S", "unit": "rpm"})
    with pytest.raises(UsageError) as exc:
        DbcCanDriver(cfg)
    assert "s3cr3t" not in str(exc.value) and "is not a DBC file" in str(exc.value)


# ----- S4: a drive deaf to neutral is not reported at neutral -----

def _sweep(write_yaml, channel, tmp_path, twin, box, during) -> int:
    """Sweep PROTOCOL on the twins; `during(twin)` runs once the first point is held."""
    import threading

    host, port = box.address
    rig = odrive_rig(write_yaml, channel, node_id=NODE)
    data = yaml.safe_load(rig.read_text())
    data["sensor"].update(host=host, port=port, http_port=box.http_port)
    rig.write_text(yaml.safe_dump(data, sort_keys=False))
    stop = threading.Event()

    def when_held() -> None:
        """`during(twin)` once a nonzero velocity setpoint has held for 0.3 s (the first
        point's ramp done), however long the sweep took to start on a loaded machine."""
        held_since, last = None, 0.0
        while not stop.wait(0.01):
            vel = twin.input_vel_turns_s
            if vel == 0.0 or vel != last:
                held_since, last = time.monotonic(), vel
            elif time.monotonic() - held_since >= 0.3:
                during(twin)
                return

    act = threading.Thread(target=when_held, daemon=True)
    act.start()
    try:
        return main(["sweep", str(write_yaml(PROTOCOL)), "--rig", str(rig), "--db",
                     str(tmp_path / "r.sqlite")])
    finally:
        stop.set()
        act.join()


@pytest.fixture
def box(live):
    from rigtool.sim.netft_twin import NetFTTwin
    twin = NetFTTwin(live).start()
    yield twin
    twin.stop()


def test_a_drive_deaf_to_neutral_exits_3_quoting_its_speed(twin, live, box, write_yaml, channel,
                                                           tmp_path, capsys):
    def deafen(t):
        t.deaf = True  # the axis holds its last setpoint, whatever rigtool sends after

    rc = _sweep(write_yaml, channel, tmp_path, twin, box, deafen)
    err = capsys.readouterr().err
    assert rc == 3, err
    assert "THE ACTUATOR MAY NOT BE AT NEUTRAL: speed feedback still reads" in err
    assert "actuator at neutral" not in err and ": None;" not in err
    from rigtool.store import Store
    with Store(tmp_path / "r.sqlite") as store:
        (run,) = store.runs()
        failed = store.events(run["id"], "neutral_failed")
    assert "may not be at neutral: speed feedback still reads" in failed[0]["detail"]["message"]
