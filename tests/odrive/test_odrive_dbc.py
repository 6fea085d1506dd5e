"""The dbc-can driver with ODrive's own DBC and the shipped odrive_velocity mapping, against
the ODrive twin over python-can virtual buses.

What rigtool sends is recorded by a second bus on the same channel and decoded with
cantools straight from the vendor file by frame id (`get_message_by_frame_id`), which
does not go through rigtool's mapping or its node-id shift: the vendor DBC lists nodes
0 to 7 itself (AxisN_..., id N << 5 | command), so node 3's frames must decode as Axis3_.
"""

from __future__ import annotations

import hashlib
import time

import cantools
import numpy as np
import pytest
from pydantic import ValidationError

from rigtool.devices.dbc_can import DBC_DIR, DbcCanConfig, DbcCanDriver, resolve
from rigtool.errors import ConfigError, DeviceError, UsageError
from rigtool.rig import load_rig
from rigtool.sim.odrive_twin import ODRIVE_DBC, OdriveTwin
from rigtool.thruster_profiles import PROFILES

from ..helpers import drain, wait_for
from .conftest import NODE

IDLE, CLOSED_LOOP_CONTROL = 1, 8
VENDOR_SHA256 = "4db07a4cef0ee1a87cfbfc779cabd7db3176072c688a694e3b8842c2dd9bcb55"
MAX_SPEED = PROFILES["can-bldc"].max_speed_rpm
VENDOR = cantools.database.load_file(str(ODRIVE_DBC))


def decode(msg) -> tuple[str, dict]:
    """A recorded frame as the vendor DBC reads it: (message name, raw signal values)."""
    message = VENDOR.get_message_by_frame_id(msg.arbitration_id)
    return message.name, message.decode(bytes(msg.data), decode_choices=False)


def test_the_vendor_file_is_shipped_unmodified():
    assert hashlib.sha256(ODRIVE_DBC.read_bytes()).hexdigest() == VENDOR_SHA256
    assert (DBC_DIR / "odrive-cansimple.LICENSE.md").read_text().startswith("MIT License")


def test_vendor_ids_are_node_shifted_by_five_from_node_0():
    """Found in the file: nodes 0..7, each command at node << 5 | cmd (can_simple.hpp)."""
    for cmd, name in ((1, "Heartbeat"), (7, "Set_Axis_State"), (9, "Get_Encoder_Estimates"),
                      (13, "Set_Input_Vel")):
        for node in range(8):
            message = VENDOR.get_message_by_name(f"Axis{node}_{name}")
            assert message.frame_id == node << 5 | cmd and not message.is_extended_frame


def test_velocity_commands_and_speed_feedback_in_rpm(twin, live, open_driver):
    driver = open_driver()
    assert driver.info.command_unit == "rpm" and driver.info.feedback == ("speed_rpm",)
    assert (driver.info.command_min, driver.info.command_max) == (-3000.0, 3000.0)
    assert driver.name == "odrive-cansimple node 3"
    assert wait_for(lambda: twin.axis_state == CLOSED_LOOP_CONTROL, 1.0)
    driver.set_command(900.0)
    assert wait_for(lambda: twin.input_vel_turns_s == pytest.approx(15.0), 1.0)
    assert live.command == pytest.approx(100 * 900 / MAX_SPEED)
    assert wait_for(lambda: abs(np.mean(live.latest().speed_rpm) - 900) < 15)
    time.sleep(0.5)
    driver.read_feedback()
    time.sleep(0.3)
    fb = driver.read_feedback()
    assert len(fb) >= 20 and np.all(np.diff(fb.t_s) > 0)  # Get_Encoder_Estimates at 100 Hz
    assert np.mean(fb.speed_rpm) == pytest.approx(900, abs=15)
    assert driver.expected_speed_rpm(900.0) == 900.0
    driver.close()
    assert wait_for(lambda: twin.axis_state == IDLE and live.command == 0.0, 1.0)
    assert twin.input_vel_turns_s == 0.0
    assert twin.requested_states == [CLOSED_LOOP_CONTROL, IDLE]


@pytest.mark.parametrize("node", [0, 3, 7])
def test_every_sent_frame_decodes_with_the_vendor_dbc(live, channel, recorder, node):
    twin = OdriveTwin(live, channel=channel, node_id=node).start()
    try:
        cfg = DbcCanConfig(driver="dbc-can", interface="virtual", channel=channel,
                           mapping="odrive_velocity", node_id=node, keepalive_s=0.05,
                           timeout_s=0.5)  # fmt: skip
        driver = DbcCanDriver(cfg)
        driver.set_command(600.0)
        driver.set_command(-450.0)
        time.sleep(0.12)  # a keep-alive or two
        driver.close()
        wait_for(lambda: len(twin.requested_states) >= 2, 2.0)  # the twin's thread has read it
    finally:
        twin.stop()
    sent = [m for m in drain(recorder) if m.arbitration_id in
            {node << 5 | 7, node << 5 | 13}]  # fmt: skip
    assert all(not m.is_extended_id and m.dlc == 8 for m in sent)
    frames = [decode(m) for m in sent]
    states = [v["Axis_Requested_State"] for n, v in frames if n == f"Axis{node}_Set_Axis_State"]
    vels = [v["Input_Vel"] for n, v in frames if n == f"Axis{node}_Set_Input_Vel"]
    assert {n for n, _ in frames} == {f"Axis{node}_Set_Axis_State", f"Axis{node}_Set_Input_Vel"}
    assert states == [CLOSED_LOOP_CONTROL, IDLE]
    neutral = (f"Axis{node}_Set_Input_Vel", {"Input_Vel": 0.0, "Input_Torque_FF": 0.0})
    first_state = next(i for i, (n, _) in enumerate(frames) if n.endswith("Set_Axis_State"))
    assert first_state > 0 and frames[:first_state] == [neutral] * first_state  # then closed loop
    assert frames[-2] == neutral
    assert frames[-1] == (f"Axis{node}_Set_Axis_State", {"Axis_Requested_State": IDLE})
    assert pytest.approx(10.0) in vels and pytest.approx(-7.5) in vels  # r/min / 60
    assert all(v["Input_Torque_FF"] == 0.0 for n, v in frames if n.endswith("Set_Input_Vel"))
    assert twin.requested_states == [CLOSED_LOOP_CONTROL, IDLE]


def test_twin_frames_are_read_back_from_the_vendor_layout(twin, recorder, open_driver):
    driver = open_driver()
    driver.set_command(1200.0)
    time.sleep(0.3)
    drain(recorder)
    driver.read_feedback()
    time.sleep(0.2)
    fb = driver.read_feedback()
    by_vendor = [decode(m) for m in drain(recorder) if m.arbitration_id >> 5 == NODE]
    vel = {round(v["Vel_Estimate"] * 60, 3) for n, v in by_vendor
           if n == "Axis3_Get_Encoder_Estimates"}  # fmt: skip
    beats = [v for n, v in by_vendor if n == "Axis3_Heartbeat"]
    assert len(fb) >= 10 and sum(round(x, 3) in vel for x in fb.speed_rpm) >= len(fb) - 2
    assert beats and all(b["Axis_State"] == CLOSED_LOOP_CONTROL and b["Axis_Error"] == 0
                         for b in beats)  # fmt: skip


def test_an_axis_error_in_the_heartbeat_stops_the_run(twin, live, open_driver):
    driver = open_driver()
    driver.set_command(600.0)
    twin.fault_code = 0x800
    assert twin.axis_state == IDLE and live.command == 0.0
    assert wait_for(lambda: driver.fault is not None, 1.0)
    with pytest.raises(DeviceError, match=r"node 3 .*Axis_Error=2048 \(WATCHDOG_TIMER_EXPIRED\)"):
        driver.read_feedback()


def test_the_twin_watchdog_trips_without_keepalive(live, channel, open_driver):
    twin = OdriveTwin(live, channel=channel, node_id=NODE, watchdog_s=0.3).start()
    try:
        driver = open_driver(keepalive_s=0)
        driver.set_command(600.0)
        assert wait_for(lambda: twin.axis_state == IDLE and live.command == 0.0, 2.0)
        assert wait_for(lambda: driver.fault is not None, 1.0)
        assert "WATCHDOG_TIMER_EXPIRED" in driver.fault
    finally:
        twin.stop()


def test_wrong_node_raises_on_open(twin, open_driver):
    with pytest.raises(DeviceError, match=r"no Axis0_Get_Encoder_Estimates/Axis0_Heartbeat "
                                          r"frames from odrive-cansimple node 4"):
        open_driver(node_id=4, timeout_s=0.3)


def test_a_node_id_beyond_11_bits_is_a_usage_error(channel):
    cfg = DbcCanConfig(driver="dbc-can", interface="virtual", channel=channel,
                       mapping="odrive_velocity", node_id=64)  # fmt: skip
    pattern = (r"node_id 64 puts Axis0_Set_Input_Vel at frame id 0x80d, beyond the 11-bit range "
               r"\(node_id 0..63 with node_id_shift 5\)")
    with pytest.raises(UsageError, match=pattern):
        DbcCanDriver(cfg)


def test_node_id_shift_also_works_for_the_own_dbc_path(channel):
    cfg = DbcCanConfig(driver="dbc-can", interface="virtual", channel=channel,
                       dbc=str(ODRIVE_DBC), node_id=2, node_id_shift=5, timeout_s=0.2,
                       command={"message": "Axis0_Set_Input_Torque", "signal": "Input_Torque",
                                "unit": "amps", "min": -1, "max": 1})  # fmt: skip
    driver = DbcCanDriver(cfg)  # no feedback configured: opens without waiting
    try:
        assert driver._frame_id(driver._cmd_msg) == 2 << 5 | 14
    finally:
        driver.close()


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"mapping": "odrive"}, r"no shipped mapping 'odrive' \(shipped: odrive_velocity, servo_driver"),
        ({"mapping": "../servo_driver"}, "no shipped mapping"),
        ({"mapping": "odrive_velocity", "node_id_shift": 29}, "less than or equal to 28"),
        ({"mapping": "servo_driver", "keepalive_s": 0}, r"0 turns the keep-alive off.*0.5 s"),
    ],
)  # fmt: skip
def test_mapping_errors_name_the_problem(fields, message):
    with pytest.raises(ValidationError, match=message):
        DbcCanConfig(driver="dbc-can", interface="virtual", channel="unused", **fields)


def test_odrive_mapping_without_watchdog_allows_keepalive_off():
    cfg = DbcCanConfig(driver="dbc-can", channel="x", mapping="odrive_velocity", keepalive_s=0)
    assert cfg.keepalive_s == 0


def test_mapping_servo_driver_is_the_default_servo_setup():
    named = resolve(DbcCanConfig(driver="dbc-can", channel="x", mapping="servo_driver"))
    default = resolve(DbcCanConfig(driver="dbc-can", channel="x"))
    assert named.model_dump(exclude={"mapping", "command_timeout_s"}) == default.model_dump(
        exclude={"mapping", "command_timeout_s"})  # fmt: skip
    assert named.command_timeout_s == 0.5 and named.dbc is None


def test_an_unknown_mapping_in_a_rig_file_names_file_and_line(write_yaml):
    text = ("name: r\nactuator:\n  driver: dbc-can\n  channel: can0\n  mapping: odrive\n"
            "sensor: {driver: ati-netft, host: h}\n")  # fmt: skip
    with pytest.raises(ConfigError, match=r"rig.yaml:5: actuator.mapping.*no shipped mapping"):
        load_rig(write_yaml(text, "rig.yaml"))
