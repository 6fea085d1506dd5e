"""VESC motor controller over CAN: duty, current or speed commands; STATUS 1/4/5 feedback.

Wire format as in the VESC firmware (comm/comm_can.c, documentation/comm_can.md):
29-bit ids `(packet_id << 8) | controller_id`, big-endian payloads.
  SET_DUTY (0)     int32 duty x 100000
  SET_CURRENT (1)  int32 A x 1000
  SET_RPM (3)      int32 electrical r/min
  STATUS (9)       int32 ERPM, int16 motor A x 10, int16 duty x 1000
  STATUS_4 (16)    int16 T_fet x 10, T_motor x 10, input A x 10, PID pos x 50
  STATUS_5 (27)    int32 tachometer, int16 input V x 10, int16 reserved
The VESC stops the motor when no command arrives within its timeout (1 s by default), so a
keep-alive thread re-sends the command in force. The fault code is not in any status
frame: the driver polls it with COMM_GET_VALUES_SELECTIVE (mask bit 15) sent as a
PROCESS_SHORT_BUFFER frame; the VESC answers with a PROCESS_SHORT_BUFFER addressed to
`host_id`.
"""

from __future__ import annotations

import logging
import struct
from typing import TYPE_CHECKING, Literal

from pydantic import ConfigDict, Field, ValidationInfo, field_validator, model_validator

from rigtool.bounds import MAX_CURRENT_A, MAX_SPEED_RPM, PositiveSeconds, Seconds
from rigtool.devices.base import ActuatorInfo, FeedbackBlock
from rigtool.devices.canbus import (
    FEEDBACK_FIELDS,
    CanActuator,
    CanBusFields,
    FeedbackBuffer,
    check_keepalive,
)
from rigtool.errors import DeviceError

if TYPE_CHECKING:  # the drivers import them when they open a bus
    import can

log = logging.getLogger(__name__)

SET_DUTY, SET_CURRENT, SET_RPM = 0, 1, 3
PROCESS_SHORT_BUFFER = 8
STATUS_1, STATUS_4, STATUS_5 = 9, 16, 27
COMM_GET_VALUES_SELECTIVE = 50
FAULT_MASK = 1 << 15  # COMM_GET_VALUES_SELECTIVE bit of the fault code (one uint8)
_SCALE = {SET_DUTY: 1e5, SET_CURRENT: 1e3, SET_RPM: 1.0}
_INT32 = (-(2**31), 2**31 - 1)
FAULT_NAMES = (
    "NONE", "OVER_VOLTAGE", "UNDER_VOLTAGE", "DRV", "ABS_OVER_CURRENT", "OVER_TEMP_FET",
    "OVER_TEMP_MOTOR", "GATE_DRIVER_OVER_VOLTAGE", "GATE_DRIVER_UNDER_VOLTAGE",
    "MCU_UNDER_VOLTAGE", "BOOTING_FROM_WATCHDOG_RESET",
)  # fmt: skip
_DEFAULT_UNIT = {"duty": "percent", "rpm": "rpm", "current": "amps"}


class VescCanConfig(CanBusFields):
    """Rig-file section for a VESC on a CAN bus (`driver: vesc-can`); the bus fields
    (interface, channel, bitrate, context, bus_args) are CanBusFields'."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    driver: Literal["vesc-can"]
    controller_id: int = Field(0, ge=0, le=254)  # VESC ID (VESC Tool: App Settings > General)
    host_id: int = Field(254, ge=0, le=254)  # our CAN id for fault-poll replies; unused by any VESC
    mode: Literal["duty", "current", "rpm"] = "duty"  # which SET_* packet carries the command
    command_unit: Literal["percent", "rpm", "amps"] | None = None  # default: percent/rpm/amps
    pole_pairs: int = Field(7, ge=1, le=1000)  # motor pole pairs: ERPM = mechanical r/min x pole_pairs
    max_erpm: float | None = Field(None, gt=0, le=MAX_SPEED_RPM * 1000)  # rpm mode: command limit, and what 100 % means
    max_current_a: float | None = Field(None, gt=0, le=MAX_CURRENT_A)  # current mode: limit, and what 100 % means
    current_source: Literal["input", "motor"] = "input"  # STATUS_4 supply A or STATUS motor A
    command_timeout_s: Seconds = 1.0  # the VESC's App Settings > Timeout; 0 = none
    keepalive_s: Seconds = Field(0.1, validate_default=True)  # re-send period; 0 = off
    timeout_s: PositiveSeconds = 1.0  # no status frame for this long -> DeviceError
    poll_fault: bool = True  # poll the fault code with every keep-alive

    @field_validator("keepalive_s")
    @classmethod
    def _keeps_alive(cls, value: float, info: ValidationInfo) -> float:
        return check_keepalive(value, info.data.get("command_timeout_s", 0.0), "VESC")

    @model_validator(mode="after")
    def _consistent(self) -> VescCanConfig:
        unit = self.unit
        allowed = {"duty": ("percent",), "rpm": ("rpm", "percent"), "current": ("amps", "percent")}
        if unit not in allowed[self.mode]:
            units = " or ".join(allowed[self.mode])
            raise ValueError(f"mode {self.mode!r} takes command_unit {units}")
        if self.mode == "rpm" and self.max_erpm is None:
            raise ValueError("mode 'rpm' needs max_erpm (electrical r/min at full command)")
        if self.mode == "current" and self.max_current_a is None:
            raise ValueError("mode 'current' needs max_current_a (motor current at full command)")
        if self.poll_fault and self.host_id == self.controller_id:
            raise ValueError("host_id must differ from controller_id")
        return self

    @property
    def unit(self) -> str:
        """The command unit in force (explicit, or the mode's default)."""
        return self.command_unit or _DEFAULT_UNIT[self.mode]


def can_id(packet: int, controller_id: int) -> int:
    """The 29-bit frame id of `packet` for (or from) `controller_id`."""
    return (packet << 8) | controller_id


def encode_command(packet: int, value: float) -> bytes:
    """Payload of SET_DUTY (duty -1..1), SET_CURRENT (A) or SET_RPM (ERPM)."""
    raw = round(value * _SCALE[packet])
    return struct.pack(">i", min(max(raw, _INT32[0]), _INT32[1]))


def decode_status1(data: bytes) -> tuple[int, float, float]:
    """STATUS: (ERPM, motor current A, duty -1..1)."""
    erpm, current, duty = struct.unpack_from(">ihh", data)
    return erpm, current / 10.0, duty / 1000.0


def decode_status4(data: bytes) -> tuple[float, float, float, float]:
    """STATUS_4: (FET temperature C, motor temperature C, input current A, PID position deg)."""
    t_fet, t_motor, current_in, pid_pos = struct.unpack_from(">hhhh", data)
    return t_fet / 10.0, t_motor / 10.0, current_in / 10.0, pid_pos / 50.0


def decode_status5(data: bytes) -> tuple[int, float]:
    """STATUS_5: (tachometer counts, input voltage V)."""
    tacho, volts = struct.unpack_from(">ih", data)
    return tacho, volts / 10.0


def fault_poll(host_id: int) -> bytes:
    """PROCESS_SHORT_BUFFER payload asking for the fault code, reply to `host_id`."""
    return bytes((host_id, 0, COMM_GET_VALUES_SELECTIVE)) + struct.pack(">I", FAULT_MASK)


def parse_fault_reply(data: bytes) -> int | None:
    """Fault code from a reply to `fault_poll` (None if the payload is something else)."""
    if len(data) != 8 or data[1] != 1 or data[2] != COMM_GET_VALUES_SELECTIVE:
        return None
    if struct.unpack_from(">I", data, 3)[0] != FAULT_MASK:
        return None
    return data[7]


def fault_name(code: int) -> str:
    """Firmware name of a fault code."""
    return f"FAULT_CODE_{FAULT_NAMES[code] if code < len(FAULT_NAMES) else code}"


def actuator_info(config: VescCanConfig) -> ActuatorInfo:
    """The command space the engine sees, from the rig file alone (a dry run opens nothing)."""
    if config.unit == "percent":
        lo, hi = -100.0, 100.0
    else:
        limit = config.max_erpm / config.pole_pairs if config.unit == "rpm" else config.max_current_a
        lo, hi = -limit, limit
    return ActuatorInfo(config.unit, 0.0, lo, hi, FEEDBACK_FIELDS)


class VescCanDriver(CanActuator):
    """Actuator on a VESC: commands in percent, r/min or A; feedback from its status frames."""

    info_for = staticmethod(actuator_info)  # the command space from a config alone (registry)

    def __init__(self, config: VescCanConfig) -> None:
        self.config = c = config
        self.name = f"VESC {c.controller_id}"
        self.info = actuator_info(c)
        self._packet = {"duty": SET_DUTY, "current": SET_CURRENT, "rpm": SET_RPM}[c.mode]
        self._feedback = FeedbackBuffer()
        self._fault = 0
        self._open_link(self._neutral_frame(), self._poll_fault if c.poll_fault else None)
        try:
            self._wait_for_first(lambda: self._feedback.last_t is not None,
                                 "is it powered, on this bus and bitrate, with CAN status "
                                 "messages 1, 4 and 5 enabled?")
            self.neutral()
        except BaseException:
            self._link.close()
            raise

    # ----- Actuator (set_command, neutral, close: CanActuator) -----

    def expected_speed_rpm(self, command: float) -> float | None:
        """In rpm mode the VESC's speed loop holds the commanded speed; otherwise unknown."""
        if self.config.mode != "rpm":
            return None
        return self._to_protocol(command) / self.config.pole_pairs

    def read_feedback(self) -> FeedbackBlock:
        """Status samples since the last call; DeviceError on a fault or on silence."""
        if self._fault:
            raise DeviceError(
                f"{self.name} on {self._link.where} reports {fault_name(self._fault)} "
                f"(code {self._fault}); the motor is stopped"
            )
        if self._silent_for(self._feedback.last_t):
            raise DeviceError(self._silence(f"for {self.config.timeout_s:g} s"))
        return self._feedback.take()

    @property
    def fault(self) -> int:
        """Latest polled fault code (0: none)."""
        return self._fault

    # ----- internals -----


    def _to_protocol(self, value: float) -> float:
        """Command in info.command_unit -> duty, A or ERPM (clipped to the range first)."""
        c = self.config
        v = min(max(value, self.info.command_min), self.info.command_max)
        if c.mode == "duty":
            return v / 100.0
        if c.mode == "current":
            return v / 100.0 * c.max_current_a if c.unit == "percent" else v
        return v / 100.0 * c.max_erpm if c.unit == "percent" else v * c.pole_pairs

    def _command_frame(self, value: float) -> can.Message:
        return self._message(self._packet, self._to_protocol(value))

    def _neutral_frame(self) -> can.Message:
        """Release the motor: SET_CURRENT 0, whatever the mode."""
        return self._message(SET_CURRENT, 0.0)

    def _message(self, packet: int, value: float) -> can.Message:
        import can
        return can.Message(
            arbitration_id=can_id(packet, self.config.controller_id),
            data=encode_command(packet, value), is_extended_id=True,
        )  # fmt: skip

    def _poll_fault(self) -> None:
        """Ask the controller for its fault code (sent with every keep-alive)."""
        import can
        self._link.send(can.Message(
            arbitration_id=can_id(PROCESS_SHORT_BUFFER, self.config.controller_id),
            data=fault_poll(self.config.host_id), is_extended_id=True,
        ))  # fmt: skip

    def _on_frame(self, msg: can.Message, t: float) -> str:
        """Decode one received frame; return the stats counter it belongs to."""
        if not msg.is_extended_id or msg.is_remote_frame:
            return "ignored"
        c = self.config
        packet, node, data = msg.arbitration_id >> 8, msg.arbitration_id & 0xFF, bytes(msg.data)
        if node == c.controller_id and packet == STATUS_1:
            if len(data) < 8:
                return "garbage"
            erpm, current, _duty = decode_status1(data)
            values = {"speed_rpm": erpm / c.pole_pairs}
            if c.current_source == "motor":
                values["current_a"] = current
            self._feedback.sample(t, **values)
        elif node == c.controller_id and packet == STATUS_4:
            if len(data) < 8:
                return "garbage"
            if c.current_source == "input":
                self._feedback.update(current_a=decode_status4(data)[2])
        elif node == c.controller_id and packet == STATUS_5:
            if len(data) < 6:
                return "garbage"
            self._feedback.update(voltage_v=decode_status5(data)[1])
        elif node == c.host_id and packet == PROCESS_SHORT_BUFFER:
            if data[:1] != bytes((c.controller_id,)):
                return "ignored"  # a reply from another controller
            code = parse_fault_reply(data)
            if code is None:
                return "garbage" if len(data) < 8 else "ignored"
            self._fault = code
        else:
            return "ignored"
        return "frames"

    def _silence(self, how: str) -> str:
        rx = f"; receive error: {self._link.rx_error}" if self._link.rx_error else ""
        return f"no status frames from {self.name} on {self._link.where} {how}{rx}"
