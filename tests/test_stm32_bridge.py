"""The STM32 bridge driver against its firmware twin over a real pty and a real TCP socket."""

from __future__ import annotations

import os
import socket
import time
from pathlib import Path

import pytest
import serial
import yaml
from pydantic import ValidationError

from rigtool.devices.base import Actuator
from rigtool.devices.stm32_bridge import (
    Stm32Bridge,
    Stm32BridgeConfig,
    counts_for,
    period_us,
    pulse_us_for,
)
from rigtool.errors import DeviceError, UsageError
from rigtool.sim.line_server import open_pty
from rigtool.sim.live import LiveTwin
from rigtool.sim.physics import ThrusterTwin
from rigtool.sim.stm32_twin import Dialect, Stm32BridgeTwin
from rigtool.thruster_profiles import PROFILES

from .helpers import wait_for as _wait_for

ROOT = Path(__file__).resolve().parent.parent
ESC_TIMER = {"psc": 71, "arr": 19999}  # 72 MHz / 72 = 1 us ticks, 20 ms period


def wait_for(predicate, timeout_s: float = 2.0) -> bool:
    """Poll `predicate` every 10 ms until it holds or `timeout_s` passes."""
    return _wait_for(predicate, timeout_s, poll_s=0.01)

LIVE_PROFILE = "stm32-pwm"  # the shared `live` fixture (conftest.py) runs this profile


@pytest.fixture
def fw(live):
    twin = Stm32BridgeTwin(live, watchdog_ms=300, seed=7).start()
    yield twin
    twin.stop()


@pytest.fixture
def open_bridge():
    """Open drivers that are always closed at the end of the test."""
    opened = []

    def _open(url: str, **fields) -> Stm32Bridge:
        fields.setdefault("watchdog_ms", 300)
        drv = Stm32Bridge(Stm32BridgeConfig(driver="stm32-bridge", url=url, **fields))
        opened.append(drv)
        return drv

    yield _open
    for drv in opened:
        drv.close()


@pytest.mark.parametrize("transport", ["pty", "socket"])
def test_set_and_read_back(fw, live, open_bridge, transport):
    url = fw.pty_path if transport == "pty" else fw.url
    drv = open_bridge(url)
    assert isinstance(drv, Actuator)
    assert drv.version == "rigtool-bridge 1.0"
    assert drv.info.command_unit == "pwm_counts"
    assert (drv.info.neutral, drv.info.command_min, drv.info.command_max) == (0, 0, 799)
    drv.set_command(420)
    assert drv.read_back() == 420
    assert fw.ccr[1] == 420
    assert live.command == 420
    drv.set_command(451.4)  # counts are integers on the wire
    assert drv.read_back() == 451
    assert drv.stats["garbage"] == 0 and drv.stats["timeouts"] == 0


def test_neutral_idempotent_and_on_close(fw, live, open_bridge):
    drv = open_bridge(fw.pty_path)
    drv.set_command(400)
    drv.neutral()
    drv.neutral()
    assert live.command == 0 and drv.command == 0
    drv.set_command(460)
    drv.close()
    assert live.command == 0
    drv.close()
    drv.neutral()  # after close: a no-op, never an error


def test_out_of_range_command_is_refused_before_sending(fw, open_bridge):
    drv = open_bridge(fw.pty_path, heartbeat_s=0)
    before = fw.lines_received
    with pytest.raises(UsageError, match="outside 0..799"):
        drv.set_command(800)
    with pytest.raises(UsageError):
        drv.set_command(float("nan"))
    assert fw.lines_received == before
    assert fw.ccr[1] == 0


def test_firmware_watchdog_stops_a_quiet_host(fw, live):
    with serial.serial_for_url(fw.pty_path, timeout=1.0) as raw:
        t_sent = time.monotonic()
        raw.write(b"SET 1 420\n")
        assert raw.readline() == b"OK 420\n"
        assert live.command == 420
        assert wait_for(lambda: fw.watchdog_trips, 2.0)
    assert live.command == 0
    assert fw.ccr == {1: 0, 2: 0, 3: 0, 4: 0}
    assert fw.watchdog_trips[0] - t_sent >= 0.3


def test_heartbeat_keeps_firmware_alive_and_stops_on_close(fw, live, open_bridge):
    drv = open_bridge(fw.url, heartbeat_s=0.05)
    drv.set_command(420)
    time.sleep(1.0)  # more than three watchdog periods
    assert fw.watchdog_trips == []
    assert live.command == 420
    assert drv.stats["heartbeats"] >= 5
    drv.close()
    assert live.command == 0
    sent = fw.lines_received
    time.sleep(0.2)
    assert fw.lines_received == sent


def test_esc_pulse_width_mode():
    live = LiveTwin(ThrusterTwin(PROFILES["esc-1100-1900"], seed=1)).start()
    fw = Stm32BridgeTwin(live, watchdog_ms=300).start()
    try:
        cfg = Stm32BridgeConfig(driver="stm32-bridge", url=fw.url, command_unit="pulse_us",
                                **ESC_TIMER)
        drv = Stm32Bridge(cfg)
        assert (drv.info.neutral, drv.info.command_min, drv.info.command_max) == (1500, 1100, 1900)
        assert live.command == 1500
        drv.set_command(1700)
        assert live.command == pytest.approx(1700)
        assert drv.read_back() == 1700  # 1 us per count
        drv.close()
        assert live.command == pytest.approx(1500)
    finally:
        fw.stop()
        live.stop()


def test_timer_conversions_match_the_stm32_formula():
    # f_PWM = f_TIM / ((PSC+1)(ARR+1)), domain.md section 6
    esc = Stm32BridgeConfig(driver="stm32-bridge", url="loop://", command_unit="pulse_us",
                            timer_clock_hz=72e6, **ESC_TIMER)
    assert 1e6 / period_us(esc) == pytest.approx(72e6 / (72 * 20000))
    assert counts_for(esc, 1500) == 1500
    assert pulse_us_for(esc, 1100) == pytest.approx(1100)
    bench = Stm32BridgeConfig(driver="stm32-bridge", url="loop://")
    assert 1e6 / period_us(bench) == pytest.approx(72e6 / 800)
    assert counts_for(bench, 427.4) == 427


def test_garbage_is_counted_and_skipped(fw, live, open_bridge):
    drv = open_bridge(fw.pty_path)
    fw.garbage = True
    drv.set_command(300)
    assert drv.read_back() == 300
    assert live.command == 300
    assert drv.stats["garbage"] >= 2
    assert drv.stats["timeouts"] == 0


def test_err_reply_is_counted_and_raised(live, open_bridge):
    fw = Stm32BridgeTwin(live, arr=499).start()  # firmware timer smaller than the config says
    try:
        drv = open_bridge(fw.pty_path)
        with pytest.raises(DeviceError, match="refused 'SET 1 700': out of range"):
            drv.set_command(700)
        assert drv.stats["errors"] == 1
        drv.set_command(450)
        assert live.command == 450
    finally:
        drv.close()
        fw.stop()


def test_missing_reply_names_the_port(fw, live, open_bridge):
    drv = open_bridge(fw.pty_path, timeout_s=0.2)
    drv.set_command(420)
    fw.no_replies = True
    with pytest.raises(DeviceError, match=f"no reply from STM32 bridge on {fw.pty_path}"):
        drv.set_command(430)
    drv.close()  # neutral goes out unconfirmed: reported, not raised
    assert live.command == 0
    assert drv.stats["timeouts"] >= 2


def test_unacknowledged_neutral_is_an_error_not_a_warning(fw, live, open_bridge):
    drv = open_bridge(fw.pty_path, timeout_s=0.2)
    drv.set_command(420)
    fw.no_replies = True
    with pytest.raises(DeviceError, match=rf"neutral not acknowledged by STM32 bridge on "
                       rf"{fw.pty_path}: no reply .*'STOP'.*; no reply .*'SET 1 0'"):
        drv.neutral()
    assert live.command == 0  # the firmware applied it, but nobody said so
    fw.no_replies = False
    drv.neutral()  # acknowledged again: no error


def test_silent_port_fails_on_open():
    master, slave, path = open_pty()
    try:
        with pytest.raises(DeviceError, match=f"no reply from STM32 bridge on {path}"):
            Stm32Bridge(Stm32BridgeConfig(driver="stm32-bridge", url=path, timeout_s=0.2))
    finally:
        os.close(master)
        os.close(slave)


def test_loop_url_echo_is_garbage_not_a_reply():
    with pytest.raises(DeviceError, match="no reply from STM32 bridge on loop://"):
        Stm32Bridge(Stm32BridgeConfig(driver="stm32-bridge", url="loop://", timeout_s=0.2))


def test_missing_port_names_it():
    with pytest.raises(DeviceError, match="cannot open /dev/ttyUSB9-rigtool-missing"):
        Stm32Bridge(Stm32BridgeConfig(driver="stm32-bridge", url="/dev/ttyUSB9-rigtool-missing"))
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(DeviceError, match=f"cannot open socket://127.0.0.1:{port}"):
        Stm32Bridge(Stm32BridgeConfig(driver="stm32-bridge", url=f"socket://127.0.0.1:{port}"))


@pytest.mark.parametrize("transport", ["pty", "socket"])
def test_disconnect_raises_and_close_survives(fw, open_bridge, transport):
    drv = open_bridge(fw.pty_path if transport == "pty" else fw.url, timeout_s=0.2)
    drv.set_command(420)
    fw.disconnect()
    with pytest.raises(DeviceError, match="STM32 bridge on"):
        drv.set_command(430)
    drv.close()


LAB_DIALECT = Dialect(set="PWM{channel}={value}", pulse="", get="PWM{channel}?", stop="HALT",
                      heartbeat="KA", ping="ID?", ok="ACK", ok_value="ACK:{value}",
                      error="NAK:{reason}", version="labfw 3.2")
LAB_CONFIG = {"set_format": "PWM{channel}={value}", "pulse_format": "",
              "get_format": "PWM{channel}?", "stop_format": "HALT", "heartbeat_format": "KA",
              "ping_format": "ID?", "reply_regex": r"ACK(?::(?P<value>.*))?",
              "error_regex": r"NAK:(?P<reason>.*)", "line_end": "\r\n", "channel": 2}


def test_custom_dialect_round_trips(live, open_bridge):
    fw = Stm32BridgeTwin(live, thruster_channel=2, dialect=LAB_DIALECT, watchdog_ms=300).start()
    try:
        drv = open_bridge(fw.pty_path, heartbeat_s=0.05, **LAB_CONFIG)
        assert drv.version == "labfw 3.2"
        drv.set_command(410)
        assert drv.read_back() == 410
        assert live.command == 410 and fw.ccr[2] == 410 and fw.ccr[1] == 0
        time.sleep(0.5)
        assert fw.watchdog_trips == [] and fw.bad_lines == 0
        other = open_bridge(fw.url, **{**LAB_CONFIG, "channel": 9})
        with pytest.raises(DeviceError, match="refused 'PWM9=100': no channel 9"):
            other.set_command(100)
        assert other.stats["errors"] == 1
        drv.neutral()
        assert live.command == 0
        with pytest.raises(DeviceError, match="no reply"):  # the default dialect cannot talk to it
            open_bridge(fw.url, timeout_s=0.2)
    finally:
        fw.stop()


def test_telemetry_becomes_feedback(live, open_bridge):
    fw = Stm32BridgeTwin(live, telemetry_hz=100).start()
    try:
        regex = r"TEL (?P<speed_rpm>\S+) (?P<current_a>\S+) (?P<voltage_v>\S+)"
        drv = open_bridge(fw.pty_path, telemetry_regex=regex)
        assert drv.info.feedback == ("speed_rpm", "current_a", "voltage_v")
        drv.set_command(400)
        drv.read_feedback()
        t0 = time.monotonic()
        time.sleep(0.3)
        fb = drv.read_feedback()
        assert len(fb) >= 10
        assert fb.t_s[0] >= t0 and (fb.t_s[1:] >= fb.t_s[:-1]).all()
        assert 10.0 < fb.voltage_v.mean() < 12.5
        assert fb.speed_rpm[-1] > 100
    finally:
        fw.stop()


def test_no_telemetry_gives_timestamps_only(fw, open_bridge):
    drv = open_bridge(fw.pty_path)
    fb = drv.read_feedback()
    assert drv.info.feedback == ()
    assert len(fb) == 0 and fb.speed_rpm is None and fb.current_a is None


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"command_unit": "pulse_us"}, "does not fit the timer"),
        ({"heartbeat_s": 0.4, "watchdog_ms": 500}, "at most half"),
        ({"set_format": "SET {ch} {value}"}, "only {channel} and {value}"),
        ({"telemetry_regex": r"T (?P<rpm>\d+)"}, "unknown groups"),
        ({"neutral": 900}, "neutral <= command_max"),
        ({"baud": 9600}, "Extra inputs"),
    ],
)
def test_config_rejects_inconsistent_settings(fields, message):
    with pytest.raises(ValidationError, match=message):
        Stm32BridgeConfig(driver="stm32-bridge", url="/dev/ttyACM0", **fields)


def test_example_rig_actuator_section_is_valid():
    rig = yaml.safe_load((ROOT / "protocols" / "rigs" / "stm32-bench.yaml").read_text())
    cfg = Stm32BridgeConfig(**rig["actuator"])
    assert cfg.arr == 799 and cfg.command_unit == "pwm_counts"
