"""rigtool's VESC frames against the VESC firmware's own CAN code, constant by constant.

Every constant below was read from GitHub vedderb/bldc at commit
b9d287b3b8323f4b02618b02dc55e57d54a84996 (files and lines at that commit) and is written
here as a literal, not imported from rigtool. The driver runs on a python-can virtual bus
against a stand-in VESC thread that packs its status frames by hand from the firmware's
layout; a second bus records what rigtool sends. No rigtool encoder, decoder or twin is
used to build or read a frame in this file.
"""

from __future__ import annotations

import struct
import threading
import time
import uuid

import can
import pytest

from rigtool.devices.vesc_can import VescCanConfig, VescCanDriver

from .helpers import drain, wait_for

# datatypes.h, enum CAN_PACKET_ID (lines 1153-1224)
CAN_PACKET_SET_DUTY = 0  # datatypes.h:1154
CAN_PACKET_SET_CURRENT = 1  # datatypes.h:1155
CAN_PACKET_SET_RPM = 3  # datatypes.h:1157
CAN_PACKET_PROCESS_SHORT_BUFFER = 8  # datatypes.h:1162
CAN_PACKET_STATUS = 9  # datatypes.h:1163
CAN_PACKET_STATUS_4 = 16  # datatypes.h:1170
CAN_PACKET_STATUS_5 = 27  # datatypes.h:1181
# datatypes.h:1012, enum COMM_PACKET_ID
COMM_GET_VALUES_SELECTIVE = 50
# comm/commands.c:442-443, case COMM_GET_VALUES_SELECTIVE: mask bit 15 = the fault code (1 byte)
FAULT_MASK_BIT = 1 << 15
# datatypes.h:145-150, enum mc_fault_code: ..., FAULT_CODE_OVER_TEMP_FET = 5
FAULT_CODE_OVER_TEMP_FET = 5

# comm/comm_can.c:507-513 comm_can_set_duty: int32(duty * 100000.0)
# comm/comm_can.c:1607-1611 decode_msg: mc_interface_set_duty(buffer_get_float32(data8, 1e5))
DUTY_SCALE = 1e5
# comm/comm_can.c:515-521 comm_can_set_current: int32(current * 1000.0)
# comm/comm_can.c:1613-1621 decode_msg: buffer_get_float32(data8, 1e3) (6-byte form: off delay first)
CURRENT_SCALE = 1e3
# comm/comm_can.c:540-546 comm_can_set_rpm: int32(rpm), electrical r/min
# comm/comm_can.c:1630-1634 decode_msg: mc_interface_set_pid_speed(buffer_get_float32(data8, 1e0))
RPM_SCALE = 1.0
# util/buffer.c:24-27 buffer_append_int16 and :34-39 buffer_append_int32: most significant
# byte first, i.e. big-endian; util/buffer.c:217-219 buffer_get_float32 = int32 / scale
INT32, INT16 = ">i", ">h"


def eid(packet: int, controller_id: int) -> int:
    """comm/comm_can.c:511 (and every sender): controller_id | ((uint32_t)packet << 8);
    decode_msg, comm_can.c:1586-1587: id = eid & 0xFF, cmd = eid >> 8."""
    return controller_id | (packet << 8)


# comm/comm_can.c:308 comm_can_transmit_eid_replace: txmsg.IDE = CAN_IDE_EXT (29-bit ids)
EXTENDED = True

# comm/comm_can.c:1216-1224 comm_can_send_status1: int32 ERPM, int16 total motor current x 1e1,
# int16 duty x 1e3 (read back at comm_can.c:2035-2046: / 10.0 and / 1000.0)
def status1(erpm: int, motor_a: float, duty: float) -> bytes:
    return (struct.pack(INT32, erpm) + struct.pack(INT16, round(motor_a * 1e1))
            + struct.pack(INT16, round(duty * 1e3)))  # fmt: skip


# comm/comm_can.c:1244-1253 comm_can_send_status4: int16 T_fet x 1e1, T_motor x 1e1,
# input current x 1e1, PID position x 50.0 (read back at comm_can.c:2078-2090)
def status4(t_fet_c: float, t_motor_c: float, input_a: float, pid_pos: float) -> bytes:
    return b"".join(struct.pack(INT16, round(x)) for x in
                    (t_fet_c * 1e1, t_motor_c * 1e1, input_a * 1e1, pid_pos * 50.0))  # fmt: skip


# comm/comm_can.c:1255-1263 comm_can_send_status5: int32 tachometer, int16 input voltage x 1e1,
# int16 reserved 0
def status5(tacho: int, volts: float) -> bytes:
    return struct.pack(INT32, tacho) + struct.pack(INT16, round(volts * 1e1)) + bytes(2)


CTRL = 42  # a controller id whose low byte is not 0
HOST = 254
POLES = 7
ERPM, MOTOR_A, INPUT_A, VOLTS = -8400, -3.7, 2.3, 47.6


class StandInVesc:
    """A VESC reduced to its CAN frames: status 1/4/5 at 100 Hz, fault-poll replies."""

    def __init__(self, channel: str, fault: int = 0) -> None:
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.fault = fault
        self.polls: list[bytes] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            for packet, data in ((CAN_PACKET_STATUS, status1(ERPM, MOTOR_A, -0.25)),
                                 (CAN_PACKET_STATUS_4, status4(31.5, 40.2, INPUT_A, 12.0)),
                                 (CAN_PACKET_STATUS_5, status5(123456, VOLTS))):  # fmt: skip
                self.bus.send(can.Message(arbitration_id=eid(packet, CTRL), data=data,
                                          is_extended_id=EXTENDED))  # fmt: skip
            msg = self.bus.recv(timeout=0.01)
            while msg is not None:
                if msg.arbitration_id == eid(CAN_PACKET_PROCESS_SHORT_BUFFER, CTRL):
                    self.polls.append(bytes(msg.data))
                    # comm/comm_can.c:443-453 comm_can_send_buffer (len <= 6): [own id, send=1,
                    # reply...] to the asker's id; commands.c:385-395: reply = id, uint32 mask
                    reply = (bytes((CTRL, 1, COMM_GET_VALUES_SELECTIVE))
                             + struct.pack(">I", FAULT_MASK_BIT) + bytes((self.fault,)))  # fmt: skip
                    self.bus.send(can.Message(arbitration_id=eid(CAN_PACKET_PROCESS_SHORT_BUFFER,
                                                                 msg.data[0]),
                                              data=reply, is_extended_id=EXTENDED))  # fmt: skip
                msg = self.bus.recv(timeout=0)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(1.0)
        self.bus.shutdown()


@pytest.fixture
def channel() -> str:
    return f"vesc-vendor-{uuid.uuid4().hex[:10]}"


@pytest.fixture
def vesc(channel):
    stand_in = StandInVesc(channel)
    yield stand_in
    stand_in.stop()


def driver_for(channel: str, **fields) -> VescCanDriver:
    return VescCanDriver(VescCanConfig(driver="vesc-can", interface="virtual", channel=channel,
                                       bitrate=None, controller_id=CTRL, host_id=HOST,
                                       pole_pairs=POLES, keepalive_s=0.05, timeout_s=0.5,
                                       **fields))  # fmt: skip


def sent(recorder, packet: int) -> list[can.Message]:
    return [m for m in drain(recorder, 0.05) if m.arbitration_id == eid(packet, CTRL)]


@pytest.mark.parametrize(
    ("fields", "command", "packet", "scale", "wire_value"),
    [
        ({"mode": "duty"}, 25.0, CAN_PACKET_SET_DUTY, DUTY_SCALE, 0.25),  # percent -> duty
        ({"mode": "duty"}, -50.0, CAN_PACKET_SET_DUTY, DUTY_SCALE, -0.5),
        ({"mode": "current", "max_current_a": 20}, 2.5, CAN_PACKET_SET_CURRENT, CURRENT_SCALE,
         2.5),
        ({"mode": "current", "max_current_a": 20}, -12.25, CAN_PACKET_SET_CURRENT, CURRENT_SCALE,
         -12.25),
        ({"mode": "rpm", "max_erpm": 12600}, 600.0, CAN_PACKET_SET_RPM, RPM_SCALE, 600.0 * POLES),
        ({"mode": "rpm", "max_erpm": 12600}, -1500.0, CAN_PACKET_SET_RPM, RPM_SCALE,
         -1500.0 * POLES),
    ],
)  # fmt: skip
def test_command_frames_match_the_firmware(vesc, channel, recorder, fields, command, packet,
                                           scale, wire_value):
    driver = driver_for(channel, **fields, poll_fault=False)
    try:
        drain(recorder)
        driver.set_command(command)
        frames = sent(recorder, packet)
    finally:
        driver.close()
    assert frames, f"no frame at id {eid(packet, CTRL):#x}"
    frame = frames[0]
    assert frame.is_extended_id is EXTENDED and frame.dlc == 4
    assert bytes(frame.data) == struct.pack(INT32, int(wire_value * scale))
    # what the firmware's decode_msg makes of it: buffer_get_float32(data8, scale)
    assert struct.unpack(INT32, bytes(frame.data))[0] / scale == pytest.approx(wire_value)


def test_neutral_is_set_current_zero(vesc, channel, recorder):
    driver = driver_for(channel, mode="rpm", max_erpm=12600, poll_fault=False)
    driver.set_command(900.0)
    drain(recorder)
    driver.close()
    (frame,) = sent(recorder, CAN_PACKET_SET_CURRENT)
    assert frame.is_extended_id and bytes(frame.data) == struct.pack(INT32, 0)


@pytest.mark.parametrize("current_source", ["input", "motor"])
def test_status_1_4_5_fields_and_scalings(vesc, channel, current_source):
    driver = driver_for(channel, mode="duty", current_source=current_source, poll_fault=False)
    try:
        time.sleep(0.15)
        fb = driver.read_feedback()
    finally:
        driver.close()
    assert len(fb) >= 5
    assert set(fb.speed_rpm) == {ERPM / POLES}  # STATUS int32 ERPM / pole pairs
    expected_a = INPUT_A if current_source == "input" else MOTOR_A  # STATUS_4 / STATUS, x 1e1
    assert fb.current_a == pytest.approx([expected_a] * len(fb))
    assert fb.voltage_v == pytest.approx([VOLTS] * len(fb))  # STATUS_5 int16 x 1e1


def test_fault_poll_and_reply_match_the_firmware(channel):
    vesc = StandInVesc(channel, fault=FAULT_CODE_OVER_TEMP_FET)
    try:
        driver = driver_for(channel, mode="duty")
        try:
            assert wait_for(lambda: driver.fault == FAULT_CODE_OVER_TEMP_FET, 1.0)
        finally:
            driver.close()
    finally:
        vesc.stop()
    # comm/comm_can.c:1769-1797 PROCESS_SHORT_BUFFER: [sender id, commands_send 0, packet...];
    # the packet: COMM_GET_VALUES_SELECTIVE, uint32 mask big-endian
    assert vesc.polls[0] == bytes((HOST, 0, COMM_GET_VALUES_SELECTIVE)) + struct.pack(
        ">I", FAULT_MASK_BIT)  # fmt: skip
