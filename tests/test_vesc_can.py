"""The vesc-can driver against the VESC twin over python-can virtual buses.

A second bus instance on the same virtual channel records every frame; the recorded
frames are decoded with cantools and tests/dbc/vesc_reference.dbc (written from the
VESC firmware documentation), independently of rigtool's own encoder and decoder.
"""

from __future__ import annotations

import time
import uuid
from pathlib import Path

import can
import cantools
import numpy as np
import pytest
import yaml
from pydantic import ValidationError

from rigtool.devices.base import Actuator
from rigtool.devices.vesc_can import VescCanConfig, VescCanDriver
from rigtool.errors import DeviceError
from rigtool.sim.vesc_twin import VescTwin
from rigtool.thruster_profiles import PROFILES

from .helpers import drain, wait_for

REFERENCE = cantools.database.load_file(str(Path(__file__).parent / "dbc" / "vesc_reference.dbc"))
ROOT = Path(__file__).resolve().parent.parent
CTRL = 5  # controller id used throughout
POLES = 7
MAX_SPEED = PROFILES["can-bldc"].max_speed_rpm

def reference(msg: can.Message, allow_truncated: bool = False) -> tuple[str, dict]:
    """(message name, signals) of a VESC frame, decoded with the reference DBC."""
    message = REFERENCE.get_message_by_frame_id(msg.arbitration_id & ~0xFF, force_extended_id=True)
    return message.name, message.decode(bytes(msg.data), allow_truncated=allow_truncated)

@pytest.fixture
def channel() -> str:
    return f"vesc-{uuid.uuid4().hex[:10]}"


@pytest.fixture
def twin(live, channel):
    twin = VescTwin(live, channel=channel, controller_id=CTRL, pole_pairs=POLES).start()
    yield twin
    twin.stop()


@pytest.fixture
def open_driver(channel):
    """Factory for drivers on the test's channel; all are closed at teardown."""
    drivers = []

    def _open(**fields) -> VescCanDriver:
        cfg = {"driver": "vesc-can", "interface": "virtual", "channel": channel,
               "controller_id": CTRL, "pole_pairs": POLES, "timeout_s": 0.5, **fields}
        driver = VescCanDriver(VescCanConfig(**cfg))
        drivers.append(driver)
        return driver

    yield _open
    for driver in drivers:
        driver.close()


def test_duty_command_drives_the_twin_and_feedback_follows(twin, live, open_driver):
    driver = open_driver()
    assert isinstance(driver, Actuator)
    assert driver.info.command_unit == "percent" and driver.info.neutral == 0.0
    driver.set_command(50.0)
    assert wait_for(lambda: abs(np.mean(live.latest().speed_rpm) - 0.5 * MAX_SPEED) < 10)
    time.sleep(1.0)  # a few more time constants: the speed is settled, only its noise is left
    driver.read_feedback()
    time.sleep(0.5)
    fb = driver.read_feedback()
    assert len(fb) >= 5  # 50 Hz status
    block = live.latest()
    assert np.all(np.diff(fb.t_s) > 0) and abs(fb.t_s[-1] - time.monotonic()) < 0.5
    assert np.mean(fb.speed_rpm) == pytest.approx(0.5 * MAX_SPEED, abs=15)
    assert np.mean(fb.current_a) == pytest.approx(np.mean(block.current_a), abs=0.4)
    assert np.mean(fb.voltage_v) == pytest.approx(np.mean(block.voltage_v), abs=0.3)
    assert driver.stats["garbage"] == 0 and driver.stats["frames"] > 0


@pytest.mark.parametrize(
    ("fields", "command", "reference_message", "signal", "expected", "twin_percent"),
    [
        ({"mode": "duty"}, 50.0, "VESC_SET_DUTY", "Duty", 0.5, 50.0),
        ({"mode": "duty"}, -12.345, "VESC_SET_DUTY", "Duty", -0.12345, -12.345),
        ({"mode": "rpm", "max_erpm": 12600}, 600.0, "VESC_SET_RPM", "ERPM", 4200, 100 * 600 / 1800),
        ({"mode": "rpm", "max_erpm": 12600, "command_unit": "percent"}, 25.0, "VESC_SET_RPM",
         "ERPM", 3150, 25.0),
        ({"mode": "current", "max_current_a": 7.0}, 1.75, "VESC_SET_CURRENT", "Current", 1.75,
         50.0),
        ({"mode": "current", "max_current_a": 7.0, "command_unit": "percent"}, -25.0,
         "VESC_SET_CURRENT", "Current", -1.75, -50.0),
    ],
)  # fmt: skip
def test_command_frames_match_the_reference_dbc(
    twin, live, recorder, open_driver, fields, command, reference_message, signal, expected,
    twin_percent,
):
    driver = open_driver(**fields)
    drain(recorder)
    driver.set_command(command)
    frames = [m for m in drain(recorder, 0.15) if m.arbitration_id & 0xFF == CTRL]
    sets = [reference(m) for m in frames if m.arbitration_id >> 8 in (0, 1, 3)]
    assert sets, "no SET_* frame on the bus"
    name, values = sets[0]
    assert name == reference_message
    assert frames[0].is_extended_id and frames[0].dlc == 4
    assert values[signal] == pytest.approx(expected, abs=1e-5)
    assert wait_for(lambda: live.command == pytest.approx(twin_percent, abs=0.01), 1.0)


def test_status_frames_decode_like_the_reference_dbc(twin, recorder, open_driver):
    driver = open_driver(mode="duty")
    driver.set_command(40.0)
    assert wait_for(lambda: abs(np.mean(twin.live.latest().speed_rpm) - 0.4 * MAX_SPEED) < 10)
    driver.read_feedback()
    drain(recorder)
    time.sleep(0.4)
    fb = driver.read_feedback()
    decoded: dict[str, list[dict]] = {}
    for msg in drain(recorder):
        if msg.arbitration_id & 0xFF == CTRL and msg.arbitration_id >> 8 in (9, 16, 27):
            name, values = reference(msg)
            decoded.setdefault(name, []).append(values)
    assert {"VESC_STATUS_1", "VESC_STATUS_4", "VESC_STATUS_5"} <= set(decoded)
    erpm = {v["ERPM"] for v in decoded["VESC_STATUS_1"]}
    current_in = {round(v["CurrentIn"], 1) for v in decoded["VESC_STATUS_4"]}
    volts = {round(v["VoltsIn"], 1) for v in decoded["VESC_STATUS_5"]}
    assert len(fb) >= 5
    # the recorder and the driver see the same frames; allow one frame at either edge
    inside = [round(s * POLES) in erpm for s in fb.speed_rpm]
    assert sum(inside) >= len(fb) - 2
    assert sum(round(c, 1) in current_in for c in fb.current_a) >= len(fb) - 3
    assert sum(round(v, 1) in volts for v in fb.voltage_v) >= len(fb) - 3
    duty = np.mean([v["Duty"] for v in decoded["VESC_STATUS_1"]])
    assert duty == pytest.approx(0.4, abs=0.02)


def test_motor_current_source_reads_status_1(twin, recorder, open_driver):
    driver = open_driver(current_source="motor")
    driver.set_command(60.0)
    time.sleep(1.0)
    driver.read_feedback()
    drain(recorder)
    time.sleep(0.3)
    fb = driver.read_feedback()
    motor = {round(reference(m)[1]["Current"], 1) for m in drain(recorder)
             if m.arbitration_id == (9 << 8) | CTRL}  # fmt: skip
    assert sum(round(c, 1) in motor for c in fb.current_a) >= len(fb) - 2
    # torque-like motor current: 7.0 A at full speed, ~0.36 of it at 60 %
    assert np.mean(fb.current_a) == pytest.approx(twin.max_motor_current_a * 0.36, abs=0.5)


def test_fault_poll_matches_reference_and_fault_raises(twin, recorder, open_driver):
    driver = open_driver(keepalive_s=0.05)
    drain(recorder, 0.2)
    twin.fault_code = 4
    frames = drain(recorder, 0.3)
    polls = [reference(m, allow_truncated=True)[1] for m in frames
             if m.arbitration_id == (8 << 8) | CTRL]  # fmt: skip
    replies = [reference(m)[1] for m in frames if m.arbitration_id == (8 << 8) | 254]
    assert polls and replies
    assert polls[0] == {"SenderId": 254, "SendMode": 0, "CommPacketId": 50,
                        "ValuesMask": 1 << 15}  # fmt: skip
    assert replies[-1]["SenderId"] == CTRL and replies[-1]["FaultCode"] == 4
    with pytest.raises(DeviceError, match=r"VESC 5 .*FAULT_CODE_ABS_OVER_CURRENT"):
        driver.read_feedback()
    twin.fault_code = 0
    assert wait_for(lambda: driver.fault == 0, 1.0)
    driver.read_feedback()


def test_keepalive_keeps_the_twin_running(live, channel, open_driver):
    twin = VescTwin(live, channel=channel, controller_id=CTRL, timeout_s=0.5).start()
    try:
        driver = open_driver(keepalive_s=0.1)
        driver.set_command(40.0)
        time.sleep(1.0)
        assert not twin.timed_out and live.command == 40.0
        driver.read_feedback()
    finally:
        twin.stop()


def test_without_keepalive_the_twin_times_out_and_stops(live, channel, open_driver):
    twin = VescTwin(live, channel=channel, controller_id=CTRL, timeout_s=0.5).start()
    try:
        driver = open_driver(keepalive_s=0, command_timeout_s=0)  # the rig file says "no timeout"
        driver.set_command(40.0)
        assert live.command == 40.0 or wait_for(lambda: live.command == 40.0, 0.5)
        assert wait_for(lambda: twin.timed_out and live.command == 0.0, 2.0)
        driver.set_command(30.0)  # the next command revives it, as on the firmware
        assert wait_for(lambda: live.command == 30.0, 0.5) and not twin.timed_out
    finally:
        twin.stop()


def test_garbage_and_error_frames_are_counted_and_skipped(twin, open_driver):
    driver = open_driver()
    driver.set_command(30.0)
    twin.garbage = True
    assert wait_for(lambda: driver.stats["garbage"] >= 5 and driver.stats["error_frames"] >= 3)
    fb = driver.read_feedback()
    assert len(fb) and np.all(np.isfinite(fb.speed_rpm)) and np.all(np.isfinite(fb.voltage_v))
    assert np.all(np.abs(fb.speed_rpm) <= MAX_SPEED * 1.1)


def test_silence_raises_device_error_naming_the_device(twin, channel, open_driver):
    driver = open_driver(timeout_s=0.3)
    driver.read_feedback()
    twin.silent = True
    time.sleep(0.5)
    with pytest.raises(DeviceError, match=rf"no status frames from VESC 5 on virtual:{channel}"):
        driver.read_feedback()
    twin.silent = False
    frames = driver.stats["frames"]
    assert wait_for(lambda: driver.stats["frames"] > frames, 1.0)
    driver.read_feedback()


def test_missing_vesc_raises_on_open(channel):
    cfg = VescCanConfig(driver="vesc-can", interface="virtual", channel=channel,
                        controller_id=CTRL, timeout_s=0.3)  # fmt: skip
    t0 = time.monotonic()
    with pytest.raises(DeviceError, match=rf"VESC 5 on virtual:{channel} within 0.3 s"):
        VescCanDriver(cfg)
    assert time.monotonic() - t0 < 1.5


def test_wrong_controller_id_is_missing(twin, channel):
    cfg = VescCanConfig(driver="vesc-can", interface="virtual", channel=channel,
                        controller_id=CTRL + 1, timeout_s=0.3)  # fmt: skip
    with pytest.raises(DeviceError, match="no status frames from VESC 6"):
        VescCanDriver(cfg)


def test_bad_interface_is_refused_by_the_config_and_a_bad_channel_by_the_driver():
    """Issue 49: an interface python-can does not know is a config error (exit 2 with
    file:line from a rig file); a known one on a missing port fails at open, naming both."""
    with pytest.raises(ValueError, match="unknown CAN interface 'no-such-interface'"):
        VescCanConfig(driver="vesc-can", interface="no-such-interface", channel="can0")
    cfg = VescCanConfig(driver="vesc-can", interface="slcan", channel="/dev/ttyNOPE9")
    with pytest.raises(DeviceError, match=r"interface='slcan' channel='/dev/ttyNOPE9'.*ttyNOPE9"):
        VescCanDriver(cfg)


def test_neutral_on_close_then_silent_and_idempotent(twin, live, recorder, open_driver):
    driver = open_driver(mode="rpm", max_erpm=12600, keepalive_s=0.05)
    driver.set_command(900.0)
    assert wait_for(lambda: live.command == pytest.approx(50.0), 1.0)
    driver.neutral()
    driver.neutral()
    assert wait_for(lambda: live.command == 0.0, 1.0)
    driver.set_command(600.0)
    drain(recorder)
    driver.close()
    ours = [m for m in drain(recorder, 0.1) if m.arbitration_id >> 8 in (0, 1, 3)
            and m.arbitration_id & 0xFF == CTRL]  # fmt: skip
    assert ours and reference(ours[-1]) == ("VESC_SET_CURRENT", {"Current": 0.0})
    assert wait_for(lambda: live.command == 0.0, 1.0)
    later = [m for m in drain(recorder, 0.3) if m.arbitration_id & 0xFF == CTRL
             and m.arbitration_id >> 8 in (0, 1, 3, 8)]  # fmt: skip
    assert later == []  # keep-alive stopped
    driver.close()
    driver.neutral()
    with pytest.raises(DeviceError, match="closed"):
        driver.set_command(10.0)


def test_transport_failure_is_a_device_error_and_close_stays_quiet(twin, channel, open_driver):
    driver = open_driver()
    driver._link._bus.shutdown()  # the adapter is unplugged under the driver
    with pytest.raises(DeviceError, match=rf"VESC 5: cannot send on virtual:{channel}"):
        driver.set_command(10.0)
    with pytest.raises(DeviceError, match="cannot send"):
        driver.neutral()  # nothing could be sent: say so
    driver.close()  # every exit path may call close; it reports, never raises
    assert driver.stats["send_errors"] >= 4


def test_commands_are_clipped_to_the_range(twin, live, open_driver):
    driver = open_driver(mode="rpm", max_erpm=12600)
    assert (driver.info.command_min, driver.info.command_max) == (-1800.0, 1800.0)
    driver.set_command(5000.0)
    assert wait_for(lambda: live.command == pytest.approx(100.0), 1.0)


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"mode": "rpm"}, "needs max_erpm"),
        ({"mode": "current"}, "needs max_current_a"),
        ({"mode": "duty", "command_unit": "amps"}, "takes command_unit percent"),
        ({"controller_id": 254}, "host_id must differ"),
        ({"interface": "virtual", "channel": "x", "speed": 3}, "Extra inputs"),
        ({"keepalive_s": 0}, r"0 turns the keep-alive off, but the VESC stops the motor 1 s"),
        ({"keepalive_s": 1.5}, r"1.5 s is too slow for the VESC's command timeout of 1 s"),
        ({"keepalive_s": 0.1, "command_timeout_s": 0.15}, r"at most half .*0.075 s"),
    ],
)
def test_config_validation(fields, message):
    with pytest.raises(ValidationError, match=message):
        VescCanConfig(**{"driver": "vesc-can", "channel": "can0", **fields})


@pytest.mark.parametrize("fields", [{}, {"keepalive_s": 0.5}, {"keepalive_s": 0, "command_timeout_s": 0},
                                    {"keepalive_s": 2.0, "command_timeout_s": 0}])
def test_keepalive_within_the_command_timeout_is_accepted(fields):
    VescCanConfig(**{"driver": "vesc-can", "channel": "can0", **fields})


def test_example_rig_file_is_valid():
    rig = yaml.safe_load((ROOT / "protocols" / "rigs" / "vesc-example.yaml").read_text())
    cfg = VescCanConfig.model_validate(rig["actuator"])
    assert cfg.driver == "vesc-can" and cfg.unit == "rpm"
