"""The dbc-can driver against the servo twin over python-can virtual buses.

Frames recorded by a second bus instance on the same virtual channel are decoded with
plain struct calls from the layout written in servo_driver.dbc (Intel byte order), so
the cross-check does not go through cantools, which the driver and the twin both use.
"""

from __future__ import annotations

import struct
import threading
import time
import uuid

import can
import numpy as np
import pytest
from pydantic import ValidationError

from rigtool.devices.base import Actuator
from rigtool.devices.dbc_can import SHIPPED_DBC, DbcCanConfig, DbcCanDriver, encode_signal, load_dbc
from rigtool.errors import DeviceError, UsageError
from rigtool.sim.dbc_twin import DbcServoTwin
from rigtool.thruster_profiles import PROFILES

from .helpers import drain, wait_for

NODE = 3
ENABLE_ID, CONTROL_ID, STATUS_ID = 0x100 + NODE, 0x200 + NODE, 0x280 + NODE
MAX_SPEED = PROFILES["can-bldc"].max_speed_rpm
def control(msg: can.Message) -> tuple[int, int]:
    """SERVO_CONTROL by hand: (ControlMode byte, raw int16 little-endian command)."""
    return msg.data[0], struct.unpack_from("<h", bytes(msg.data), 1)[0]


def status(msg: can.Message) -> tuple[float, float, float, int]:
    """SERVO_STATUS by hand: speed 0.1 r/min, current 0.01 A, voltage 0.01 V, fault code."""
    speed, current, volts, fault = struct.unpack_from("<hhHB", bytes(msg.data))
    return speed * 0.1, current * 0.01, volts * 0.01, fault


@pytest.fixture
def channel() -> str:
    return f"servo-{uuid.uuid4().hex[:10]}"


LIVE_SEED = 2  # seed of the shared `live` fixture (conftest.py)


@pytest.fixture
def twin(live, channel):
    twin = DbcServoTwin(live, channel=channel, node_id=NODE, watchdog_s=0.5).start()
    yield twin
    twin.stop()


@pytest.fixture
def open_driver(channel):
    """Factory for drivers on the test's channel; all are closed at teardown."""
    drivers = []

    def _open(**fields) -> DbcCanDriver:
        cfg = {"driver": "dbc-can", "interface": "virtual", "channel": channel,
               "node_id": NODE, "timeout_s": 0.5, **fields}
        driver = DbcCanDriver(DbcCanConfig(**cfg))
        drivers.append(driver)
        return driver

    yield _open
    for driver in drivers:
        driver.close()


def test_shipped_mapping_drives_the_twin_and_feedback_follows(twin, live, open_driver):
    driver = open_driver()
    assert isinstance(driver, Actuator)
    assert driver.info.command_unit == "percent"
    assert (driver.info.command_min, driver.info.command_max) == (-100.0, 100.0)
    assert driver.info.feedback == ("speed_rpm", "current_a", "voltage_v")
    assert wait_for(lambda: twin.enabled, 1.0)
    driver.set_command(50.0)
    assert wait_for(lambda: abs(np.mean(live.latest().speed_rpm) - 0.5 * MAX_SPEED) < 10)
    time.sleep(1.0)  # a few more time constants: the speed is settled, only its noise is left
    driver.read_feedback()
    time.sleep(0.5)
    fb = driver.read_feedback()
    block = live.latest()
    assert len(fb) >= 5 and np.all(np.diff(fb.t_s) > 0)
    assert abs(fb.t_s[-1] - time.monotonic()) < 0.5
    assert np.mean(fb.speed_rpm) == pytest.approx(0.5 * MAX_SPEED, abs=15)
    assert np.mean(fb.current_a) == pytest.approx(np.mean(block.current_a), abs=0.4)
    assert np.mean(fb.voltage_v) == pytest.approx(np.mean(block.voltage_v), abs=0.3)
    assert driver.stats["garbage"] == 0


@pytest.mark.parametrize(
    ("command", "value", "mode", "raw", "twin_percent"),
    [
        (None, 50.0, 2, 5000, 50.0),
        (None, -33.33, 2, -3333, -33.33),
        ({"message": "SERVO_CONTROL", "signal": "SpeedCmd_rpm", "unit": "rpm"}, 600.0, 1, 600,
         100 * 600 / 1800),
        ({"message": "SERVO_CONTROL", "signal": "SpeedCmd_rpm", "unit": "percent", "scale": 18},
         25.0, 1, 450, 25.0),
        ({"message": "SERVO_CONTROL", "signal": "CurrentCmd_A", "unit": "amps", "min": -7,
          "max": 7}, 1.75, 3, 175, 50.0),
    ],
)  # fmt: skip
def test_command_frames_match_the_dbc_layout(
    twin, live, recorder, open_driver, command, value, mode, raw, twin_percent
):
    driver = open_driver(**({"command": command} if command else {}))
    drain(recorder)
    driver.set_command(value)
    frames = [m for m in drain(recorder, 0.15) if m.arbitration_id == CONTROL_ID]
    assert frames and not frames[0].is_extended_id and frames[0].dlc == 8
    assert control(frames[0]) == (mode, raw)
    assert wait_for(lambda: live.command == pytest.approx(twin_percent, abs=0.01), 1.0)


def test_status_frames_decode_like_the_dbc_layout(twin, recorder, open_driver):
    driver = open_driver()
    driver.set_command(40.0)
    time.sleep(0.3)
    driver.read_feedback()
    drain(recorder)
    time.sleep(0.3)
    fb = driver.read_feedback()
    by_hand = [status(m) for m in drain(recorder) if m.arbitration_id == STATUS_ID]
    assert len(fb) >= 5 and by_hand
    speeds = {round(s[0], 1) for s in by_hand}
    currents = {round(s[1], 2) for s in by_hand}
    volts = {round(s[2], 2) for s in by_hand}
    assert sum(round(x, 1) in speeds for x in fb.speed_rpm) >= len(fb) - 2
    assert sum(round(x, 2) in currents for x in fb.current_a) >= len(fb) - 2
    assert sum(round(x, 2) in volts for x in fb.voltage_v) >= len(fb) - 2
    assert {s[3] for s in by_hand} == {0}


def test_enable_on_start_and_neutral_then_disable_on_close(twin, live, recorder, channel):
    cfg = DbcCanConfig(driver="dbc-can", interface="virtual", channel=channel, node_id=NODE,
                       keepalive_s=0.05)  # fmt: skip
    driver = DbcCanDriver(cfg)
    first = [m for m in drain(recorder) if m.arbitration_id in (ENABLE_ID, CONTROL_ID)]
    assert control(first[0]) == (2, 0)  # neutral before enabling
    assert any(m.arbitration_id == ENABLE_ID and m.data[0] & 1 == 1 for m in first)
    driver.set_command(60.0)
    assert wait_for(lambda: live.command == pytest.approx(60.0), 1.0)
    drain(recorder)
    driver.close()
    ours = [m for m in drain(recorder, 0.1) if m.arbitration_id in (ENABLE_ID, CONTROL_ID)]
    assert control(ours[-2]) == (2, 0) and ours[-1].arbitration_id == ENABLE_ID
    assert ours[-1].data[0] & 1 == 0
    assert wait_for(lambda: not twin.enabled and live.command == 0.0, 1.0)
    later = [m for m in drain(recorder, 0.3) if m.arbitration_id in (ENABLE_ID, CONTROL_ID)]
    assert later == []  # keep-alive stopped
    driver.close()
    driver.neutral()
    with pytest.raises(DeviceError, match="closed"):
        driver.set_command(1.0)


def test_keepalive_feeds_the_servo_watchdog(twin, live, open_driver):
    driver = open_driver(keepalive_s=0.1)
    driver.set_command(40.0)
    time.sleep(0.8)
    assert not twin.timed_out and live.command == 40.0
    driver.read_feedback()


def test_without_keepalive_the_servo_stops_and_reports_comm_timeout(twin, live, open_driver):
    driver = open_driver(keepalive_s=0, command_timeout_s=0)  # the rig file says "no watchdog"
    driver.set_command(40.0)
    assert wait_for(lambda: live.command == 40.0, 0.5)
    assert wait_for(lambda: twin.timed_out and live.command == 0.0, 2.0)
    assert wait_for(lambda: driver.fault is not None, 0.5)
    with pytest.raises(DeviceError, match=r"servo_driver node 3 .*FaultCode=7 \(CommTimeout\)"):
        driver.read_feedback()
    driver.set_command(20.0)
    assert wait_for(lambda: driver.fault is None and live.command == 20.0, 1.0)


def test_fault_code_stops_the_motor_and_raises(twin, live, open_driver):
    driver = open_driver()
    driver.set_command(50.0)
    twin.fault_code = 1
    assert live.command == 0.0
    assert wait_for(lambda: driver.fault is not None, 1.0)
    with pytest.raises(DeviceError, match=r"FaultCode=1 \(OverCurrent\)"):
        driver.read_feedback()
    driver.set_command(50.0)
    time.sleep(0.1)
    assert live.command == 0.0  # ignored while in fault
    twin.fault_code = 0
    assert wait_for(lambda: driver.fault is None, 1.0)
    driver.read_feedback()


def test_garbage_and_error_frames_are_counted_and_skipped(twin, open_driver):
    driver = open_driver()
    driver.set_command(30.0)
    twin.garbage = True
    assert wait_for(lambda: driver.stats["garbage"] >= 5 and driver.stats["error_frames"] >= 5)
    fb = driver.read_feedback()
    assert len(fb) and all(np.all(np.isfinite(getattr(fb, k))) for k in driver.info.feedback)


def test_silence_raises_device_error_naming_the_device(twin, channel, open_driver):
    driver = open_driver(timeout_s=0.3)
    twin.silent = True
    time.sleep(0.5)
    pattern = rf"no SERVO_STATUS frames from servo_driver node 3 on virtual:{channel}"
    with pytest.raises(DeviceError, match=pattern):
        driver.read_feedback()
    twin.silent = False
    time.sleep(0.1)
    driver.read_feedback()


def test_missing_servo_or_wrong_node_raises_on_open(twin, channel):
    cfg = DbcCanConfig(driver="dbc-can", interface="virtual", channel=channel, node_id=NODE + 1,
                       timeout_s=0.3)  # fmt: skip
    with pytest.raises(DeviceError, match=rf"node 4 on virtual:{channel} within 0.3 s"):
        DbcCanDriver(cfg)


def test_bad_interface_is_refused_and_a_bad_channel_raises_device_error_naming_it():
    """An unknown interface is a config error (issue 49); a known one on a missing port
    fails at open with a DeviceError naming interface and channel."""
    with pytest.raises(ValueError, match="unknown CAN interface 'no-such-interface'"):
        DbcCanConfig(driver="dbc-can", interface="no-such-interface", channel="can7")
    cfg = DbcCanConfig(driver="dbc-can", interface="slcan", channel="/dev/ttyNOPE7")
    with pytest.raises(DeviceError, match=r"interface='slcan' channel='/dev/ttyNOPE7'"):
        DbcCanDriver(cfg)


def test_feedback_scale_and_a_custom_dbc(tmp_path, live, channel, recorder):
    """A drive with its own DBC (absolute extended ids, Motorola order, shaft r/min x 5)."""
    dbc = tmp_path / "gearmotor.dbc"
    dbc.write_text(
        'VERSION ""\n\nNS_ :\n\nBS_:\n\nBU_: HOST DRIVE\n\n'
        "BO_ 2164269056 SPEED_SET: 2 HOST\n"
        ' SG_ ShaftRpm : 7|16@0- (1,0) [-10000|10000] "rpm" DRIVE\n\n'
        "BO_ 2164269057 SPEED_ACT: 2 DRIVE\n"
        ' SG_ ShaftRpm : 7|16@0- (1,0) [-10000|10000] "rpm" HOST\n'
    )  # fmt: skip
    cfg = DbcCanConfig(
        driver="dbc-can", interface="virtual", channel=channel, dbc=str(dbc), node_id=0,
        command={"message": "SPEED_SET", "signal": "ShaftRpm", "unit": "rpm", "scale": 5},
        feedback={"speed_rpm": {"message": "SPEED_ACT", "signal": "ShaftRpm", "scale": 0.2}},
        timeout_s=0.5,
    )
    drive = can.Bus(interface="virtual", channel=channel)
    stop = False

    def answer():
        while not stop:
            msg = drive.recv(timeout=0.02)
            if msg is not None and msg.arbitration_id == 0x1002000:
                drive.send(can.Message(arbitration_id=0x1002001, data=msg.data))

    thread = threading.Thread(target=answer, daemon=True)
    thread.start()
    try:
        driver = DbcCanDriver(cfg)
        assert (driver.info.command_min, driver.info.command_max) == (-2000.0, 2000.0)
        driver.set_command(300.0)
        sent = [m for m in drain(recorder, 0.1) if m.arbitration_id == 0x1002000]
        assert sent[-1].is_extended_id and struct.unpack(">h", bytes(sent[-1].data)) == (1500,)
        assert wait_for(lambda: driver.stats["frames"] > 0)
        fb = driver.read_feedback()
        assert fb.speed_rpm[-1] == pytest.approx(300.0) and fb.current_a is None
        driver.close()
    finally:
        stop = True
        thread.join(1.0)
        drive.shutdown()


def test_encode_signal_selects_the_multiplexer():
    message = load_dbc(SHIPPED_DBC).get_message_by_name("SERVO_CONTROL")
    assert encode_signal(message, "SpeedCmd_rpm", -1200.0) == bytes((1,)) + struct.pack(
        "<h", -1200) + bytes(5)  # fmt: skip
    assert encode_signal(message, "CurrentCmd_A", 99.0)[:3] == bytes((3,)) + struct.pack("<h", 2000)


@pytest.mark.parametrize(
    ("fields", "error", "message"),
    [
        ({"dbc": "x.dbc"}, ValidationError, "give `command"),
        ({"command": {"message": "NOPE", "signal": "X"}}, UsageError,
         "no message 'NOPE'.*SERVO_CONTROL"),
        ({"command": {"message": "SERVO_CONTROL", "signal": "Speed"}}, UsageError,
         "no signal 'Speed'.*SpeedCmd_rpm"),
        ({"dbc": "/no/such.dbc", "command": {"message": "A", "signal": "B"}}, UsageError,
         "/no/such.dbc: file not found"),
        ({"neutral": 150.0}, UsageError, "neutral 150 outside"),
        ({"command": {"message": "SERVO_CONTROL", "signal": "SpeedCmd_pct", "scale": 0}},
         ValidationError, "scale must not be 0"),
        ({"enable": {"message": "SERVO_ENABLE", "signal": "Enable", "on": 1}}, ValidationError,
         "Extra inputs"),
        ({"keepalive_s": 0}, ValidationError, r"0 turns the keep-alive off.*0.5 s after"),
        ({"keepalive_s": 0.3}, ValidationError, r"too slow for the drive's command timeout of 0.5"),
        ({"keepalive_s": 0.2, "command_timeout_s": 0.3}, ValidationError, r"at most half .*0.15 s"),
    ],
)  # fmt: skip
def test_config_errors_name_the_problem(fields, error, message):
    with pytest.raises(error, match=message):
        DbcCanDriver(DbcCanConfig(**{"driver": "dbc-can", "interface": "virtual",
                                     "channel": f"unused-{uuid.uuid4().hex[:6]}", **fields}))
