"""The shipped servo (rigtool/dbc/servo_driver.dbc) on a python-can bus, driven by the live twin.

Behaves like the pool rig's speed/current servo: SERVO_ENABLE switches the power stage;
SERVO_CONTROL commands speed (r/min or percent of max) or motor current, and must be
repeated within `watchdog_s` or the servo stops and reports CommTimeout; SERVO_STATUS
(speed, supply current, bus voltage, fault code) goes out at `status_hz` and
SERVO_HEARTBEAT (NMT state) at `heartbeat_hz`. Frame ids are the DBC's plus `node_id`.

Fault switches: `silent` (transmits nothing), `deaf` (receives nothing, so its watchdog
stops the motor), `garbage` (adds truncated status frames and error frames), `fault_code`
(a FaultCode value: motor stopped, commands ignored, reported).
"""

from __future__ import annotations

import math
import time

import can
import cantools

from rigtool.devices.dbc_can import SHIPPED_DBC
from rigtool.sim.can_twin import CanBusTwin
from rigtool.sim.live import LiveTwin

COMM_TIMEOUT = 7  # FaultCode value table: CommTimeout
_NMT_OPERATIONAL, _NMT_PREOPERATIONAL, _NMT_STOPPED = 5, 127, 4


def _clip(x: float, lo: float, hi: float) -> float:
    """Keep a value inside its DBC signal range."""
    return min(max(x, lo), hi)


class DbcServoTwin(CanBusTwin):
    """Simulated servo_driver.dbc drive at `node_id` on a python-can bus, in front of a LiveTwin."""

    thread_name = "servo-twin"

    def __init__(
        self,
        live: LiveTwin,
        channel: str,
        interface: str = "virtual",
        node_id: int = 1,
        status_hz: float = 50.0,
        heartbeat_hz: float = 5.0,
        watchdog_s: float = 0.5,
        bitrate: int | None = None,
    ) -> None:
        super().__init__(live, channel, interface, bitrate)
        self.node_id = node_id
        self.status_hz = status_hz
        self.heartbeat_hz = heartbeat_hz
        self.watchdog_s = watchdog_s
        self.db = cantools.database.load_file(str(SHIPPED_DBC))
        p = self.profile
        self.max_motor_current_a = p.cn * p.max_speed_rpm**3  # motor current at max speed
        # observable state
        self.enabled = False
        self.timed_out = False
        self.commands: list[tuple[str, float]] = []  # (signal, value) of every applied command
        self._last_control_t: float | None = None

    @property
    def address(self) -> dict:
        """What a dbc-can rig section needs to reach this twin."""
        return {"interface": self.interface, "channel": self.channel, "node_id": self.node_id}

    # ----- receiving -----

    def _rx_loop(self) -> None:
        enable_id = self._id("SERVO_ENABLE")
        control_id = self._id("SERVO_CONTROL")
        while not self._stop.is_set():
            try:
                msg = self._bus.recv(timeout=0.02)
            except can.CanError:
                continue
            if msg is None or self.deaf or msg.is_error_frame or msg.is_extended_id:
                continue
            if msg.arbitration_id not in (enable_id, control_id):
                continue
            name = "SERVO_ENABLE" if msg.arbitration_id == enable_id else "SERVO_CONTROL"
            try:
                values = self.db.get_message_by_name(name).decode(bytes(msg.data),
                                                                  decode_choices=False)
            except (cantools.database.DecodeError, ValueError):
                continue
            if name == "SERVO_ENABLE":
                self._set_enabled(bool(values["Enable"]))
            else:
                self._control(values)

    def _set_enabled(self, on: bool) -> None:
        self.enabled = on
        if not on:
            self._last_control_t = None
            self.timed_out = False
            self.live.set_command(self.profile.neutral)

    def _control(self, values: dict) -> None:
        if not self.enabled:
            return
        self._last_control_t = time.monotonic()
        self.timed_out = False
        if self._fault_code:
            return
        mode = values["ControlMode"]
        signal = {1: "SpeedCmd_rpm", 2: "SpeedCmd_pct", 3: "CurrentCmd_A"}.get(mode)
        value = float(values[signal]) if signal else 0.0
        self.commands.append((signal or "Off", value))
        self.live.set_command(self._percent(signal, value))

    def _percent(self, signal: str | None, value: float) -> float:
        """The profile's percent command equivalent to a SERVO_CONTROL command."""
        if signal == "SpeedCmd_pct":
            return value
        if signal == "SpeedCmd_rpm":
            return 100.0 * value / self.profile.max_speed_rpm
        if signal == "CurrentCmd_A":  # propeller torque ~ n^2 balances motor current
            frac = min(1.0, abs(value) / self.max_motor_current_a)
            return math.copysign(100.0 * math.sqrt(frac), value)
        return self.profile.neutral

    # ----- transmitting -----

    def _tx_loop(self) -> None:
        period = 1.0 / self.status_hz
        beat_every = max(1, round(self.status_hz / self.heartbeat_hz))
        next_t = time.monotonic()
        tick = 0
        while not self._stop.wait(max(0.0, next_t - time.monotonic())):
            now = time.monotonic()
            next_t = max(next_t + period, now)
            self._check_watchdog(now)
            block = self.live.latest()
            if block is not None:
                self._send_status(block)
            if tick % beat_every == 0:
                self._send("SERVO_HEARTBEAT", {"NmtState": self._nmt_state()})
            tick += 1

    def _check_watchdog(self, now: float) -> None:
        t = self._last_control_t
        if t is not None and not self.timed_out and now - t > self.watchdog_s:
            self.timed_out = True
            self.live.set_command(self.profile.neutral)

    def _reported_fault(self) -> int:
        return self._fault_code or (COMM_TIMEOUT if self.timed_out else 0)

    def _nmt_state(self) -> int:
        if self._reported_fault():
            return _NMT_STOPPED
        return _NMT_OPERATIONAL if self.enabled else _NMT_PREOPERATIONAL

    def _send_status(self, block) -> None:
        values = {
            "ActualSpeed_rpm": _clip(float(block.speed_rpm[-1]), -3000.0, 3000.0),
            "Current_A": _clip(float(block.current_a[-1]), -50.0, 50.0),
            "BusVoltage_V": _clip(float(block.voltage_v[-1]), 0.0, 100.0),
            "FaultCode": self._reported_fault(),
            "Enabled": int(self.enabled),
        }
        data = self._send("SERVO_STATUS", values)
        if self.garbage and data is not None:
            self._send_raw(self._id("SERVO_STATUS"), data[:3])
            self._send_raw(0x20000000 | 0x80, bytes(8), error=True)

    def _id(self, name: str) -> int:
        return self.db.get_message_by_name(name).frame_id + self.node_id

    def _send(self, name: str, values: dict) -> bytes | None:
        data = self.db.get_message_by_name(name).encode(values)
        return data if self._send_raw(self._id(name), data) else None

    def _send_raw(self, arbitration_id: int, data: bytes, error: bool = False) -> bool:
        return self._send_frame(arbitration_id, data, extended=error, error=error)
