"""LineFramer, shared by the drivers and the twins' LineServer: the drivers' behaviour kept
(checked against a model of it on seeded chunkings), linear time, and the twins' cap (a line
without an end costs bounded memory and linear time, over a real pty)."""

from __future__ import annotations

import contextlib
import os
import random
import select
import time
import tty

import pytest

from rigtool.devices.framing import LineFramer
from rigtool.sim.live import LiveTwin
from rigtool.sim.physics import ThrusterTwin
from rigtool.sim.stm32_twin import Stm32BridgeTwin
from rigtool.thruster_profiles import PROFILES


class ModelFramer:
    """The drivers' framing as specified: split the whole buffer at CR/LF, drop an overlong
    partial line (the obvious quadratic way)."""

    def __init__(self, max_line: int | None) -> None:
        self.max_line, self.buf = max_line, b""

    def feed(self, data: bytes) -> tuple[list[bytes], bool]:
        *lines, self.buf = (self.buf + data).replace(b"\r", b"\n").split(b"\n")
        overflow = self.max_line is not None and len(self.buf) > self.max_line
        if overflow:
            self.buf = b""
        return [line for line in lines if line], overflow


@pytest.mark.parametrize("max_line", [None, 8, 40])
def test_driver_framing_is_unchanged_on_seeded_chunkings(max_line):
    rng = random.Random(1234)
    alphabet = b"ab \r\n\x00\xff"
    for _ in range(200):
        framer, model = LineFramer(max_line), ModelFramer(max_line)
        for _ in range(rng.randint(1, 12)):
            chunk = bytes(rng.choice(alphabet) for _ in range(rng.randint(0, 30)))
            assert framer.feed(chunk) == model.feed(chunk)


def test_keep_overlong_hands_back_the_head_of_a_long_line_at_its_end():
    framer = LineFramer(4, keep_overlong=True)
    assert framer.feed(b"abcdefgh") == ([], False)
    assert framer.feed(b"ij\nok\r\n\nxy") == ([b"abcde", b"ok"], False)
    framer.clear()  # a watchdog trip: the partial `xy` is gone
    assert framer.feed(b"z\n") == ([b"z"], False)


def test_feeding_two_megabytes_without_a_line_end_is_linear():
    framer = LineFramer()  # no cap: the worst case
    chunk = b"A" * 4096
    t0 = time.perf_counter()
    for _ in range(2 * 1024 * 1024 // len(chunk)):
        framer.feed(chunk)
    assert time.perf_counter() - t0 < 1.0  # was quadratic: the buffer re-joined every read
    lines, overflow = framer.feed(b"\nOK\n")
    assert [len(line) for line in lines] == [2 * 1024 * 1024, 2] and not overflow


def test_the_twin_refuses_two_megabytes_without_a_line_end_quickly_and_answers_on():
    live = LiveTwin(ThrusterTwin(PROFILES["stm32-pwm"], seed=1)).start()
    twin = Stm32BridgeTwin(live).start()
    fd = os.open(twin.pty_path, os.O_RDWR | os.O_NOCTTY)
    try:
        tty.setraw(fd)
        os.set_blocking(fd, False)
        data, sent, out = b"A" * 2_000_000 + b"\nPING\n", 0, b""
        t0 = time.monotonic()
        while out.count(b"\n") < 2 and time.monotonic() - t0 < 10:
            if sent < len(data):
                with contextlib.suppress(BlockingIOError):
                    sent += os.write(fd, data[sent:sent + 4096])
            if select.select([fd], [], [], 0.001)[0]:
                out += os.read(fd, 4096)
        elapsed = time.monotonic() - t0
    finally:
        os.close(fd)
        twin.stop()
        live.stop()
    assert out == b"ERR line too long\nOK rigtool-bridge 1.0\n"
    assert elapsed < 6.0  # 13 s before the cap; about 0.6 s now
