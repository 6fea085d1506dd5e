"""A VESC on a python-can bus, driven by the live physics twin (profile "can-bldc").

Serves the real wire protocol (ids `(packet << 8) | controller_id`, big-endian, as in
the VESC firmware's comm_can.c): applies SET_DUTY / SET_CURRENT / SET_RPM to the twin,
broadcasts STATUS, STATUS_4 and STATUS_5 at `status_hz`, answers the fault-code poll
(COMM_GET_VALUES_SELECTIVE in a PROCESS_SHORT_BUFFER frame), and stops the motor when
commands stop for `timeout_s`, like the firmware's App Settings > Timeout.

Commands map onto the profile's percent command: duty d -> 100 d %; ERPM e -> the
mechanical speed e / pole_pairs as a percent of the profile's max speed; motor current
I -> the speed where propeller torque (~ n^2) balances it, 100 sqrt(|I| / I_max) % with
I_max the motor current at max speed. Fault switches: `silent` (transmits nothing),
`deaf` (receives nothing, so its command timeout stops the motor), `garbage` (adds
truncated status frames and error frames), `fault_code` (motor stopped, commands ignored,
code reported by the poll).
"""

from __future__ import annotations

import math
import struct
import time

import can

from rigtool.sim.can_twin import CanBusTwin
from rigtool.sim.live import LiveTwin

_SET_DUTY, _SET_CURRENT, _SET_RPM = 0, 1, 3
_PROCESS_SHORT_BUFFER = 8
_STATUS_1, _STATUS_4, _STATUS_5 = 9, 16, 27
_GET_VALUES_SELECTIVE = 50
_FAULT_BIT = 1 << 15
_BROADCAST = 255
_TEMP_FET_C, _TEMP_MOTOR_C = 32.0, 38.0
_MIN_DUTY_FOR_CURRENT = 0.05


def _int16(x: float) -> int:
    return max(-32768, min(32767, round(x)))


class VescTwin(CanBusTwin):
    """Simulated VESC on a python-can bus (`interface`, `channel`) in front of a LiveTwin."""

    thread_name = "vesc-twin"

    def __init__(
        self,
        live: LiveTwin,
        channel: str,
        interface: str = "virtual",
        controller_id: int = 0,
        pole_pairs: int = 7,
        status_hz: float = 50.0,
        timeout_s: float = 1.0,
        bitrate: int | None = None,
    ) -> None:
        super().__init__(live, channel, interface, bitrate)
        self.controller_id = controller_id
        self.pole_pairs = pole_pairs
        self.status_hz = status_hz
        self.timeout_s = timeout_s
        p = self.profile
        self.max_motor_current_a = p.cn * p.max_speed_rpm**3  # motor current at max speed
        # observable state for tests and `rigtool sim`
        self.commands: list[tuple[int, float]] = []  # (packet id, value) of every applied SET_*
        self.timed_out = False
        self.polls = 0
        self._last_command_t: float | None = None
        self._tacho = 0.0

    @property
    def address(self) -> dict:
        """What a vesc-can rig section needs to reach this twin."""
        return {"interface": self.interface, "channel": self.channel,
                "controller_id": self.controller_id, "pole_pairs": self.pole_pairs,
                "command_timeout_s": self.timeout_s}

    # ----- receiving -----

    def _rx_loop(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self._bus.recv(timeout=0.02)
            except can.CanError:
                continue
            if msg is None or self.deaf or not msg.is_extended_id or msg.is_error_frame:
                continue
            packet, node = msg.arbitration_id >> 8, msg.arbitration_id & 0xFF
            if node not in (self.controller_id, _BROADCAST):
                continue
            data = bytes(msg.data)
            if packet in (_SET_DUTY, _SET_CURRENT, _SET_RPM) and len(data) >= 4:
                self._apply(packet, data)
            elif packet == _PROCESS_SHORT_BUFFER and len(data) >= 7:
                self._answer_poll(data)

    def _apply(self, packet: int, data: bytes) -> None:
        raw = struct.unpack_from(">i", data)[0]
        value = raw / {_SET_DUTY: 1e5, _SET_CURRENT: 1e3, _SET_RPM: 1.0}[packet]
        self._last_command_t = time.monotonic()
        self.timed_out = False
        if self._fault_code:
            return
        self.commands.append((packet, value))
        self.live.set_command(self._percent(packet, value))

    def _percent(self, packet: int, value: float) -> float:
        """The profile's percent command equivalent to a SET_* value."""
        if packet == _SET_DUTY:
            return 100.0 * value
        if packet == _SET_RPM:
            return 100.0 * value / self.pole_pairs / self.profile.max_speed_rpm
        frac = min(1.0, abs(value) / self.max_motor_current_a)
        return math.copysign(100.0 * math.sqrt(frac), value)

    def _answer_poll(self, data: bytes) -> None:
        sender, send_mode, command = data[0], data[1], data[2]
        mask = struct.unpack_from(">I", data, 3)[0]
        if send_mode != 0 or command != _GET_VALUES_SELECTIVE or mask != _FAULT_BIT:
            return  # this twin only answers the fault-code poll
        self.polls += 1
        payload = bytes((self.controller_id, 1, _GET_VALUES_SELECTIVE))
        payload += struct.pack(">IB", _FAULT_BIT, self._fault_code)
        self._send((_PROCESS_SHORT_BUFFER << 8) | sender, payload)

    # ----- broadcasting -----

    def _tx_loop(self) -> None:
        period = 1.0 / self.status_hz
        next_t = time.monotonic()
        last_t = next_t
        while not self._stop.wait(max(0.0, next_t - time.monotonic())):
            now = time.monotonic()
            next_t = max(next_t + period, now)
            self._check_timeout(now)
            block = self.live.latest()
            if block is None:
                continue
            speed = float(block.speed_rpm[-1])
            erpm = speed * self.pole_pairs
            self._tacho += 6.0 * erpm / 60.0 * (now - last_t)  # 6 counts per electrical turn
            last_t = now
            self._broadcast(speed, erpm, float(block.current_a[-1]), float(block.voltage_v[-1]))

    def _check_timeout(self, now: float) -> None:
        t = self._last_command_t
        if t is not None and not self.timed_out and now - t > self.timeout_s:
            self.timed_out = True
            self.live.set_command(self.profile.neutral)

    def _broadcast(self, speed: float, erpm: float, current_in: float, voltage: float) -> None:
        p = self.profile
        duty = max(-1.0, min(1.0, speed / p.max_speed_rpm))
        # motor current ~ torque ~ n^2; the supply-current noise rides on it
        steady_in = p.cn * abs(speed) ** 3 + p.idle_current_a
        motor = math.copysign(self.max_motor_current_a * duty**2, speed) + current_in - steady_in
        if abs(duty) < _MIN_DUTY_FOR_CURRENT:
            motor = current_in - steady_in
        tacho = (int(self._tacho) + 2**31) % 2**32 - 2**31
        frames = [
            (_STATUS_1, struct.pack(">ihh", round(erpm), _int16(motor * 10), _int16(duty * 1000))),
            (_STATUS_4, struct.pack(">hhhh", _int16(_TEMP_FET_C * 10), _int16(_TEMP_MOTOR_C * 10),
                                    _int16(current_in * 10), 0)),
            (_STATUS_5, struct.pack(">ihh", tacho, _int16(voltage * 10), 0)),
        ]  # fmt: skip
        for packet, payload in frames:
            self._send((packet << 8) | self.controller_id, payload)
        if self.garbage:
            self._send((_STATUS_1 << 8) | self.controller_id, frames[0][1][:5])
            self._send((_STATUS_5 << 8) | self.controller_id, frames[2][1][:3])
            self._send(0x20000000 | 0x80, bytes(8), error=True)

    def _send(self, arbitration_id: int, data: bytes, error: bool = False) -> None:
        self._send_frame(arbitration_id, data, extended=True, error=error)
