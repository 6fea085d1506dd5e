"""An ODrive axis speaking CAN Simple on a python-can bus, driven by the live physics twin.

Frames are encoded and decoded with cantools from ODrive's own DBC (rigtool/dbc/
odrive-cansimple.dbc, node 0's messages) at ids `node_id << 5 | command id`, as the
firmware's can_simple.cpp does. Set_Axis_State moves the axis between IDLE (1) and
CLOSED_LOOP_CONTROL (8), Clear_Errors clears what its watchdog set; Set_Input_Vel (turns/s) is applied in closed loop, as a percent
of the profile's max speed; Heartbeat (axis error, state) goes out at `heartbeat_hz` and
Get_Encoder_Estimates (position, velocity) at `encoder_hz`, the firmware's default 100 ms
and 10 ms. With `watchdog_s` > 0 the axis, like axis.config.enable_watchdog, drops to IDLE
with WATCHDOG_TIMER_EXPIRED when no frame reaches it for that long.

Fault switches: `silent` (transmits nothing), `deaf` (receives nothing), `garbage` (adds
truncated encoder frames and error frames), `fault_code` (an Axis_Error value: the axis
drops to IDLE, the motor stops, closed loop is refused until it is cleared),
`no_heartbeat` (heartbeats stop, encoder frames go on), `vel_estimate` (a value, e.g.
NaN, sent as Vel_Estimate instead of the speed).
"""

from __future__ import annotations

import time

import can
import cantools

from rigtool.devices.dbc_can import DBC_DIR
from rigtool.sim.can_twin import CanBusTwin
from rigtool.sim.live import LiveTwin

ODRIVE_DBC = DBC_DIR / "odrive-cansimple.dbc"
NODE_SHIFT = 5  # can_simple.hpp: NUM_CMD_ID_BITS = 11 - NUM_NODE_ID_BITS (6)
MAX_NODE_ID = 0x3F
IDLE, CLOSED_LOOP_CONTROL = 1, 8  # Axis_State value table
WATCHDOG_TIMER_EXPIRED = 0x800  # Axis_Error value table
_RECEIVED = ("Axis0_Set_Axis_State", "Axis0_Set_Input_Vel", "Axis0_Clear_Errors")


class OdriveTwin(CanBusTwin):
    """Simulated ODrive axis at `node_id` on a python-can bus, in front of a LiveTwin."""

    thread_name = "odrive-twin"

    def __init__(
        self,
        live: LiveTwin,
        channel: str,
        interface: str = "virtual",
        node_id: int = 0,
        encoder_hz: float = 100.0,
        heartbeat_hz: float = 10.0,
        watchdog_s: float = 0.0,
        bitrate: int | None = None,
    ) -> None:
        if not 0 <= node_id <= MAX_NODE_ID:
            raise ValueError(f"ODrive node ids are 0..{MAX_NODE_ID}, got {node_id}")
        super().__init__(live, channel, interface, bitrate)
        self.node_id = node_id
        self.encoder_hz = encoder_hz
        self.heartbeat_hz = heartbeat_hz
        self.watchdog_s = watchdog_s
        self.db = cantools.database.load_file(str(ODRIVE_DBC))
        # observable state
        self.axis_state = IDLE
        self.axis_error = 0
        self.input_vel_turns_s = 0.0
        self.no_heartbeat = False  # fault switch: stop the heartbeat only
        self.vel_estimate: float | None = None  # fault switch: report this Vel_Estimate
        self.requested_states: list[int] = []  # every Axis_Requested_State received
        self.input_vels: list[float] = []  # every Input_Vel received (turns/s)
        self._pos_turns = 0.0
        self._last_rx_t: float | None = None

    @property
    def address(self) -> dict:
        """What a dbc-can rig section with `mapping: odrive_velocity` needs to reach this twin."""
        return {"interface": self.interface, "channel": self.channel, "node_id": self.node_id}

    @property
    def fault_code(self) -> int:
        return self._fault_code

    @fault_code.setter
    def fault_code(self, code: int) -> None:
        """Set an axis error (0 clears it); an error drops the axis to IDLE at once."""
        self._fault_code = int(code)
        if code:
            self._idle()

    # ----- receiving -----

    def _rx_loop(self) -> None:
        ids = {self._id(name): name for name in _RECEIVED}
        while not self._stop.is_set():
            try:
                msg = self._bus.recv(timeout=0.02)
            except can.CanError:
                continue
            if msg is None or self.deaf or msg.is_error_frame or msg.is_extended_id:
                continue
            if msg.arbitration_id >> NODE_SHIFT != self.node_id:
                continue
            self._last_rx_t = time.monotonic()  # can_simple.cpp: any frame feeds the watchdog
            name = ids.get(msg.arbitration_id)
            if name is None or msg.is_remote_frame:
                continue
            try:
                values = self.db.get_message_by_name(name).decode(bytes(msg.data),
                                                                  decode_choices=False)
            except (cantools.database.DecodeError, ValueError):
                continue
            if name == "Axis0_Set_Axis_State":
                self._request_state(int(values["Axis_Requested_State"]))
            elif name == "Axis0_Clear_Errors":
                self.axis_error = 0
            else:
                self._input_vel(float(values["Input_Vel"]))

    def _request_state(self, state: int) -> None:
        self.requested_states.append(state)
        if state == IDLE:
            self._idle()
        elif state == CLOSED_LOOP_CONTROL and not self._error():
            self.axis_state = CLOSED_LOOP_CONTROL
            self.live.set_command(self._percent(self.input_vel_turns_s))

    def _input_vel(self, turns_s: float) -> None:
        self.input_vels.append(turns_s)
        self.input_vel_turns_s = turns_s
        if self.axis_state == CLOSED_LOOP_CONTROL:
            self.live.set_command(self._percent(turns_s))

    def _percent(self, turns_s: float) -> float:
        """The profile's percent command for a velocity setpoint, clipped to its range."""
        p = self.profile
        return min(max(100.0 * turns_s * 60.0 / p.max_speed_rpm, p.command_min), p.command_max)

    def _idle(self) -> None:
        self.axis_state = IDLE
        self.live.set_command(self.profile.neutral)

    def _error(self) -> int:
        return self._fault_code | self.axis_error

    # ----- transmitting -----

    def _tx_loop(self) -> None:
        period = 1.0 / self.encoder_hz
        beat_every = max(1, round(self.encoder_hz / self.heartbeat_hz))
        next_t = last_t = time.monotonic()
        tick = 0
        while not self._stop.wait(max(0.0, next_t - time.monotonic())):
            now = time.monotonic()
            next_t = max(next_t + period, now)
            self._check_watchdog(now)
            block = self.live.latest()
            if block is not None:
                vel_turns_s = float(block.speed_rpm[-1]) / 60.0
                self._pos_turns += vel_turns_s * (now - last_t)
                reported = vel_turns_s if self.vel_estimate is None else self.vel_estimate
                data = self._send("Axis0_Get_Encoder_Estimates",
                                  {"Pos_Estimate": self._pos_turns, "Vel_Estimate": reported})
                if self.garbage and data is not None:
                    self._send_frame(self._id("Axis0_Get_Encoder_Estimates"), data[:3],
                                     extended=False)
                    self._send_frame(0x20000000 | 0x80, bytes(8), extended=True, error=True)
            last_t = now
            if tick % beat_every == 0 and not self.no_heartbeat:
                self._send("Axis0_Heartbeat", {
                    "Axis_Error": self._error(), "Axis_State": self.axis_state,
                    "Motor_Error_Flag": 0, "Encoder_Error_Flag": 0,
                    "Controller_Error_Flag": 0, "Trajectory_Done_Flag": 0})
            tick += 1

    def _check_watchdog(self, now: float) -> None:
        t = self._last_rx_t
        if (self.watchdog_s > 0 and self.axis_state == CLOSED_LOOP_CONTROL and t is not None
                and now - t > self.watchdog_s):
            self.axis_error |= WATCHDOG_TIMER_EXPIRED
            self._idle()

    def _id(self, name: str) -> int:
        return self.db.get_message_by_name(name).frame_id | (self.node_id << NODE_SHIFT)

    def _send(self, name: str, values: dict) -> bytes | None:
        data = self.db.get_message_by_name(name).encode(values)
        return data if self._send_frame(self._id(name), data, extended=False) else None
