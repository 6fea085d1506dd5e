"""The bridge firmware (firmware/bridge) under rigtool's real stm32-bridge driver, over ptys.

Two builds serve the same C core: the host build (gcc, POSIX pty) and the bare-metal
STM32F405 build running in QEMU (netduinoplus2, USART1 on a pty). Both meet the same
driver test, and one scripted conversation gets the same replies from them as from the twin.
"""

from __future__ import annotations

import os
import random
import re
import select
import shutil
import subprocess
import sys
import time
import tty
from fractions import Fraction
from pathlib import Path

import pytest
import yaml

from rigtool.devices.stm32_bridge import Stm32Bridge, Stm32BridgeConfig
from rigtool.errors import DeviceError
from rigtool.sim.live import LiveTwin
from rigtool.sim.physics import ThrusterTwin
from rigtool.sim.stm32_twin import Stm32BridgeTwin
from rigtool.thruster_profiles import PROFILES

ROOT = Path(__file__).resolve().parent.parent
FW = ROOT / "firmware" / "bridge"
CC = shutil.which("gcc") or shutil.which("cc")
ARM_CC = shutil.which("arm-none-eabi-gcc")
QEMU = shutil.which("qemu-system-arm")
C_FLAGS = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic"]
NO_CC = "no C compiler (gcc or cc) on PATH"
NO_QEMU = ("QEMU test needs arm-none-eabi-gcc and qemu-system-arm "
           "(apt-get install -y --no-install-recommends gcc-arm-none-eabi qemu-system-arm)")
WATCHDOG_S = 0.5  # bridge_rig.h: the bench rig's watchdog_ms
BOOT_TIMEOUT_S = 20.0


class Served:
    """A running firmware build: its pty path, its process, and (host build) its trace file."""

    def __init__(self, proc: subprocess.Popen, pty_path: str, trace: Path | None = None) -> None:
        self.proc, self.pty_path, self.trace = proc, pty_path, trace
        self.keeper: int | None = None  # holds the QEMU pty open across driver opens

    def trace_lines(self) -> list[list[str]]:
        """The host build's compare-value trace: [t_ms, 'ccr', ch, value, cause] rows."""
        assert self.trace is not None
        return [line.split() for line in self.trace.read_text().splitlines()]

    def stop(self) -> None:
        if self.keeper is not None:
            os.close(self.keeper)
        self.proc.terminate()
        try:
            self.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(timeout=5)


@pytest.fixture(scope="module")
def host_binary(tmp_path_factory) -> Path:
    if CC is None:
        pytest.skip(NO_CC)
    out = tmp_path_factory.mktemp("fw-host") / "bridge_host"
    subprocess.run([CC, *C_FLAGS, "-O2", "-o", str(out), "host/bridge_host.c", "bridge_core.c"],
                   cwd=FW, check=True, capture_output=True, text=True)
    return out


@pytest.fixture(scope="module")
def qemu_image(tmp_path_factory) -> Path:
    if ARM_CC is None or QEMU is None:
        pytest.skip(NO_QEMU)
    out = tmp_path_factory.mktemp("fw-qemu") / "bridge_qemu.elf"
    subprocess.run([ARM_CC, *C_FLAGS, "-Os", "-mthumb", "-mcpu=cortex-m4", "-ffreestanding",
                    "-nostdlib", "-T", "qemu/stm32f405.ld", "-o", str(out), "qemu/startup.c",
                    "qemu/main.c", "bridge_core.c", "-lgcc"],
                   cwd=FW, check=True, capture_output=True, text=True)
    return out


def serve_host(binary: Path, tmp_path: Path, *extra: str) -> Served:
    trace = tmp_path / "trace.txt"
    proc = subprocess.Popen([str(binary), "--pty", "--trace", str(trace), *extra],
                            stdout=subprocess.PIPE, text=True)
    return Served(proc, proc.stdout.readline().strip(), trace)


def exchange(fd: int, line: bytes, timeout_s: float = 2.0) -> bytes:
    """Write one line to a raw pty fd and read back one reply line."""
    os.write(fd, line)
    buf, deadline = b"", time.monotonic() + timeout_s
    while not buf.endswith(b"\n"):
        left = deadline - time.monotonic()
        if left <= 0 or not select.select([fd], [], [], left)[0]:
            raise TimeoutError(f"no reply to {line!r} (got {buf!r})")
        buf += os.read(fd, 256)
    return buf


def serve_qemu(image: Path) -> Served:
    proc = subprocess.Popen([QEMU, "-M", "netduinoplus2", "-nographic", "-monitor", "none",
                             "-serial", "pty", "-kernel", str(image)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    served = Served(proc, "")
    try:
        line = proc.stdout.readline()
        match = re.search(r"(/dev/pts/\d+)", line)
        assert match, f"QEMU did not report its pty: {line!r}"
        served.pty_path = match.group(1)
        # QEMU notices a pty's other end by polling once a second: keep one end open, and
        # wait until the firmware answers before any driver opens the port.
        served.keeper = os.open(served.pty_path, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(served.keeper)
        deadline = time.monotonic() + BOOT_TIMEOUT_S
        while True:
            try:
                if exchange(served.keeper, b"PING\n", 0.5) == b"OK rigtool-bridge 1.0\n":
                    break
            except TimeoutError:
                assert time.monotonic() < deadline, "the emulated STM32 never answered PING"
    except BaseException:
        served.stop()
        raise
    return served


@pytest.fixture(params=["host", "qemu"])
def firmware(request, tmp_path):
    if request.param == "host":
        served = serve_host(request.getfixturevalue("host_binary"), tmp_path)
    else:
        served = serve_qemu(request.getfixturevalue("qemu_image"))
    yield served
    served.stop()


def bridge(url: str, **fields) -> Stm32Bridge:
    return Stm32Bridge(Stm32BridgeConfig(driver="stm32-bridge", url=url, watchdog_ms=500, **fields))


def _silent_until_neutral(drv: Stm32Bridge, tries: int = 6) -> int:
    """Stay silent for longer than the watchdog period, then read the output; again, each time
    silent longer, while the firmware (slowed by a loaded machine) has not yet acted. Every
    line feeds the watchdog, so each try is a whole silent period of its own."""
    for k in range(tries):
        time.sleep(WATCHDOG_S + 0.4 * (k + 1))
        value = drv.read_back()
        if value == 0:
            return value
    return value


def _count_up(drv: Stm32Bridge, counter: str, n: int, limit_s: float = 30.0) -> None:
    """Wait until the driver's `counter` reaches `n` (a count, not a wall-clock window)."""
    start = time.monotonic()
    while drv.stats[counter] < n:
        assert time.monotonic() - start < limit_s, f"{counter}: {drv.stats[counter]} of {n}"
        time.sleep(0.02)


def test_driver_against_firmware(firmware):
    drv = bridge(firmware.pty_path, heartbeat_s=0.1)
    try:
        assert drv.version == "rigtool-bridge 1.0"
        drv.set_command(420)
        assert drv.read_back() == 420
        _count_up(drv, "heartbeats", 8)  # 3 watchdog periods of heartbeats keep it fed
        assert drv.read_back() == 420
        assert drv.stats["heartbeat_failures"] == 0
        drv.neutral()  # STOP
        assert drv.read_back() == 0
        drv.set_command(799)
        assert drv.read_back() == 799
    finally:
        drv.close()
    assert drv.stats["errors"] == drv.stats["garbage"] == drv.stats["timeouts"] == 0

    # PW: 72 MHz, PSC 0 -> 72 counts per us
    pw = bridge(firmware.pty_path, command_unit="pulse_us", command_min=0, command_max=11,
                neutral=0, heartbeat_s=0.1)
    try:
        pw.set_command(5)
        assert pw.read_back() == 360
    finally:
        pw.close()

    other = bridge(firmware.pty_path, channel=9, heartbeat_s=0)
    try:
        with pytest.raises(DeviceError, match="refused 'SET 9 100': no channel 9"):
            other.set_command(100)
    finally:
        other.close()

    # the host goes silent: no heartbeat, and the watchdog puts the output back to neutral
    quiet = bridge(firmware.pty_path, heartbeat_s=0)
    try:
        quiet.set_command(460)
        assert quiet.read_back() == 460
        assert _silent_until_neutral(quiet) == 0
    finally:
        quiet.close()
    if firmware.trace is not None:  # the firmware's own clock: tripped one period after 460
        rows = [(int(r[0]), r[2:]) for r in firmware.trace_lines()]
        t_cmd = max(t for t, r in rows if r == ["1", "460", "command"])
        t_trip = min(t for t, r in rows if r == ["1", "0", "watchdog"] and t >= t_cmd)
        assert t_trip - t_cmd >= WATCHDOG_S * 1000


def test_telemetry_lines_become_feedback(host_binary, tmp_path):
    served = serve_host(host_binary, tmp_path, "--telemetry-ms", "10")
    try:
        regex = r"TEL (?P<speed_rpm>\S+) (?P<current_a>\S+) (?P<voltage_v>\S+)"
        drv = bridge(served.pty_path, telemetry_regex=regex)
        drv.set_command(420)
        drv.read_feedback()
        time.sleep(0.3)
        fb = drv.read_feedback()
        drv.close()
    finally:
        served.stop()
    assert len(fb) >= 10
    # the host build's stand-in sample: ccr * 1.0 rpm, ccr mA, 12.00 V
    assert fb.speed_rpm[-1] == 420.0 and fb.current_a[-1] == 0.42 and fb.voltage_v[-1] == 12.0
    assert drv.stats["garbage"] == 0


PROTOCOL = """\
rigtool_protocol: 1
name: firmware-bridge
command: {unit: pwm_counts, values: [0, 300, 420]}
depth: {unit: m, values: [1.0], mode: preset}
timing: {settle: {seconds: 0.3}, acquire: {samples: 100, rate_hz: 1000}, rest_s: 0.1,
         tare: per_depth, tare_s: 0.2}
limits: {max_thrust_n: 20}
"""


def test_rigtool_sweep_through_the_firmware(host_binary, tmp_path):
    from rigtool.sim.server import start_sim

    sim = start_sim("stm32-pwm", sensor="netft", netft="127.0.0.1:0")  # the force sensor
    served = serve_host(host_binary, tmp_path)
    try:
        rig = {**sim.rig, "depth_stage": None,
               "actuator": {**sim.rig["actuator"], "url": served.pty_path}}
        (tmp_path / "rig.yaml").write_text(yaml.safe_dump(rig))
        (tmp_path / "p.yaml").write_text(PROTOCOL)
        done = subprocess.run([sys.executable, "-m", "rigtool.cli", "sweep", "p.yaml", "--rig",
                               "rig.yaml", "--db", "runs.sqlite"],
                              cwd=tmp_path, capture_output=True, text=True, timeout=120)
    finally:
        served.stop()
        sim.stop()
    assert done.returncode == 0, done.stderr
    commands = [int(r[3]) for r in served.trace_lines() if r[2] == "1" and r[4] == "command"]
    assert {300, 420} <= set(commands)
    assert commands[-1] == 0  # the sweep's last command: neutral


CONVERSATION = [
    b"PING\n", b"SET 1 420\n", b"GET 1\n", b"PW 1 5\n", b"GET 1\n", b"PW 1 11\n", b"PW 1 12\n",
    b"PW 1 -1\n", b"PW 1 -0\n", b"SET 1 799\n", b"SET 1 800\n", b"SET 1 -1\n", b"SET 1 +12\n",
    b"SET 1 -0\n", b"SET 1 99999999999999999999999\n", b"SET 5 10\n", b"SET 0 10\n",
    b"SET 99999999999999999999 1\n", b"GET 007\n", b"GET 0\n", b"GET 4\n", b"SET 1 4.5\n",
    b"set 1 1\n", b"FOO\n", b"SET  1 5\n", b"SET 1\n", b"STOPX\n", b"  HB  \n", b"\tPING\x0b\n",
    b"HB\r\n", b"\rGET 1\r", b"A" * 65 + b"\n", b"SET 1 7" + b" " * 57 + b"\n",
    b"SET 1 8" + b" " * 58 + b"\n", b"\xff\xfe\x80abc\n", b"\x00\x01\n", b"PING" + b"\x80" * 70 + b"\n",
    b"SET 2 5\n", b"STOP\n", b"GET 1\n", b"GET 2\n", b"HB\n",
]


def converse(path: str, lines: list[bytes]) -> list[bytes]:
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
    try:
        tty.setraw(fd)
        return [exchange(fd, line) for line in lines]
    finally:
        os.close(fd)


def twin_replies(lines: list[bytes]) -> list[bytes]:
    """The twin's answers (stm32-pwm: 72 MHz, PSC 0, ARR 799, neutral 0, like bridge_rig.h)."""
    live = LiveTwin(ThrusterTwin(PROFILES["stm32-pwm"], seed=1)).start()
    twin = Stm32BridgeTwin(live).start()
    try:
        return converse(twin.pty_path, lines)
    finally:
        twin.stop()
        live.stop()


def test_same_conversation_same_replies_from_twin_and_firmware(firmware):
    from_twin = twin_replies(CONVERSATION)
    assert converse(firmware.pty_path, CONVERSATION) == from_twin
    replies = dict(zip(CONVERSATION, from_twin, strict=True))
    assert replies[b"A" * 65 + b"\n"] == b"ERR line too long\n"
    assert replies[b"SET 1 7" + b" " * 57 + b"\n"] == b"OK 7\n"  # 64 bytes: the longest line
    assert replies[b"\xff\xfe\x80abc\n"] == b"ERR bad line\n"
    assert replies[b"SET 1 800\n"] == b"ERR out of range 0..799\n"
    assert replies[b"FOO\n"] == b"ERR unknown command\n"
    assert replies[b"SET 99999999999999999999 1\n"] == b"ERR no channel 99999999999999999999\n"


TOKENS = ["SET", "PW", "GET", "STOP", "HB", "PING", " ", " ", " ", "  ", "\t", "\x0c", "\x1f", "0",
          "1", "2", "4", "5", "9", "12", "799", "800", "-", "+", "007", "99999999999999999999",
          ".", "x", "\x00", "\x7f", "\x80", "\xff", "set", "A" * 30]


def random_lines(seed: int, n: int) -> list[bytes]:
    """Seeded hostile lines: token soup and near-miss commands, each non-empty, LF-ended."""
    rng = random.Random(seed)
    out = []
    for _ in range(n):
        if rng.random() < 0.5:
            text = "".join(rng.choice(TOKENS) for _ in range(rng.randint(1, 8)))
        else:
            cmd = rng.choice(["SET", "PW", "GET"])
            text = f"{cmd} {rng.choice(['1', '4', '5', '0', '01'])} {rng.randint(-50, 900)}"
            if cmd == "GET":
                text = text.rsplit(" ", 1)[0]
        out.append(text.encode("latin-1") + b"\n")
    return out


def test_seeded_hostile_lines_get_the_twins_replies(firmware):
    lines = random_lines(2017, 200)
    from_twin = twin_replies(lines)
    from_firmware = converse(firmware.pty_path, lines)
    assert [(line, got) for line, got, want in zip(lines, from_firmware, from_twin, strict=True)
            if got != want] == []
    assert len(set(from_twin)) > 20  # the soup reaches many different answers


# Timers whose tick is no whole number of nanoseconds: `PW` lands on exact halves of a count.
INEXACT_TICKS = [(72_000_000, 47), (72_000_000, 79), (72_000_000, 95),
                 (84_000_000, 7), (84_000_000, 15), (84_000_000, 55)]


def pw_lines(clock_hz: int, psc: int, arr: int = 799) -> list[bytes]:
    """PW values from 0 through the top of the range (ties included) for this timer."""
    top_us = (2 * arr + 1) * (psc + 1) * 1_000_000 // (2 * clock_hz)  # ~ (ARR + 1/2) ticks
    values = [*range(0, 40), *range(top_us - 3, top_us + 4), -1, -0]
    return [f"PW 1 {v}\n".encode() for v in values] + [b"GET 1\n"]


@pytest.mark.parametrize(("clock_hz", "psc"), INEXACT_TICKS)
def test_pw_rounds_the_same_in_twin_and_firmware_at_inexact_ticks(host_binary, tmp_path,
                                                                  clock_hz, psc):
    lines = pw_lines(clock_hz, psc)
    live = LiveTwin(ThrusterTwin(PROFILES["stm32-pwm"], seed=1)).start()
    twin = Stm32BridgeTwin(live, timer_clock_hz=clock_hz, psc=psc).start()
    try:
        from_twin = converse(twin.pty_path, lines)
    finally:
        twin.stop()
        live.stop()
    served = serve_host(host_binary, tmp_path, "--clock-hz", str(clock_hz), "--psc", str(psc))
    try:
        from_firmware = converse(served.pty_path, lines)
    finally:
        served.stop()
    assert [(line, got) for line, got, want in zip(lines, from_firmware, from_twin, strict=True)
            if got != want] == []
    # the doc's rule: counts = us * f_TIM / (10^6 (PSC+1)), nearest, exact halves to even
    for line, got in zip(lines, from_twin, strict=False):
        us = int(line.split()[2]) if line.startswith(b"PW") else None
        if us is not None and us >= 0:
            exact = Fraction(us * clock_hz, 1_000_000 * (psc + 1))
            want = round(exact)  # Fraction rounds halves to even, exactly
            assert got == (f"OK {want}\n".encode() if want <= 799
                           else b"ERR out of range 0..799\n")
    if (clock_hz, psc) == (72_000_000, 47):
        replies = dict(zip(lines, from_twin, strict=True))
        assert replies[b"PW 1 1\n"] == b"OK 2\n"  # 1.5 counts: the even neighbour
        assert replies[b"PW 1 533\n"] == b"ERR out of range 0..799\n"  # 799.5 -> 800


def cut_off_by_the_watchdog(path: str) -> list[bytes]:
    """`SET 1 700` without its line end, silence past the watchdog, then the line end."""
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
    try:
        tty.setraw(fd)
        armed = exchange(fd, b"SET 1 300\n")
        os.write(fd, b"SET 1 700")
        time.sleep(WATCHDOG_S + 0.5)  # the watchdog trips to neutral meanwhile
        after = exchange(fd, b"\nGET 1\n")  # the empty line is no line: GET's reply only
        time.sleep(0.1)
        late = os.read(fd, 256) if select.select([fd], [], [], 0.2)[0] else b""
        return [armed, after, late]
    finally:
        os.close(fd)


def test_a_watchdog_trip_discards_the_partial_line_in_twin_and_firmware(firmware):
    live = LiveTwin(ThrusterTwin(PROFILES["stm32-pwm"], seed=1)).start()
    twin = Stm32BridgeTwin(live, watchdog_ms=round(WATCHDOG_S * 1000)).start()
    try:
        from_twin = cut_off_by_the_watchdog(twin.pty_path)
        assert twin.ccr[1] == 0 and len(twin.watchdog_trips) == 1
    finally:
        twin.stop()
        live.stop()
    assert from_twin == [b"OK 300\n", b"OK 0\n", b""]
    assert cut_off_by_the_watchdog(firmware.pty_path) == from_twin
    if firmware.trace is not None:
        assert ["1", "700"] not in [r[2:4] for r in firmware.trace_lines()]


# The Arduino Servo build: 1 us counts at 50 Hz, but the Servo library puts out 544..2400 us.
SERVO_ARGS = ("--clock-hz", "1000000", "--psc", "0", "--arr", "19999", "--neutral", "1500",
              "--ccr-min", "544", "--ccr-max", "2400")
SERVO_LINES = [b"SET 1 19999\n", b"GET 1\n", b"SET 1 2400\n", b"SET 1 2401\n", b"GET 1\n",
               b"PW 1 543\n", b"PW 1 544\n", b"SET 1 0\n", b"SET 1 -0\n", b"GET 1\n"]


def test_servo_output_range_is_refused_beyond_what_the_servo_library_puts_out(host_binary,
                                                                              tmp_path):
    live = LiveTwin(ThrusterTwin(PROFILES["esc-1100-1900"], seed=1)).start()
    twin = Stm32BridgeTwin(live, timer_clock_hz=1e6, psc=0, arr=19999,
                           ccr_range=(544, 2400)).start()
    try:
        from_twin = converse(twin.pty_path, SERVO_LINES)
    finally:
        twin.stop()
        live.stop()
    served = serve_host(host_binary, tmp_path, *SERVO_ARGS)
    try:
        assert converse(served.pty_path, SERVO_LINES) == from_twin
    finally:
        served.stop()
    refused = b"ERR out of range 544..2400\n"
    assert from_twin == [refused, b"OK 1500\n", b"OK 2400\n", refused, b"OK 2400\n", refused,
                         b"OK 544\n", refused, refused, b"OK 544\n"]


CXX = shutil.which("g++")


def build_arduino_sketch(tmp_path: Path, *defines: str) -> Path:
    """The Arduino sketch's glue compiled for the host on stand-ins for Serial and Servo
    (tests/arduino_stub: Servo clamps like the library), with the real core."""
    stub = ROOT / "tests" / "arduino_stub"
    core = tmp_path / "bridge_core.o"
    subprocess.run([CC, *C_FLAGS, "-c", "bridge_core.c", "-o", str(core)], cwd=FW, check=True,
                   capture_output=True, text=True)
    out = tmp_path / "bridge_ino"
    subprocess.run([CXX, "-std=c++11", "-Wall", "-Wextra", "-Werror", *defines, "-I", ".",
                    "-I", str(stub), "-include", "Arduino.h", "-x", "c++", "arduino/bridge.ino",
                    "-x", "none", str(stub / "main.cpp"), str(core), "-o", str(out)],
                   cwd=FW, check=True, capture_output=True, text=True)
    return out


def test_the_arduino_servo_glue_answers_only_what_its_pins_carry(tmp_path):
    if CC is None or CXX is None:
        pytest.skip("no gcc and g++ on PATH")
    sketch = build_arduino_sketch(tmp_path)
    lines = "PING\nSET 1 19999\nGET 1\nSET 1 2000\nPW 2 543\nPW 2 2400\nGET 1\nGET 2\n"
    done = subprocess.run([str(sketch)], input=lines, capture_output=True, text=True,
                          timeout=10, check=True)
    refused = "ERR out of range 544..2400"
    assert done.stdout.splitlines() == [
        "OK rigtool-bridge 1.0", refused, "OK 1500", "OK 2000", refused, "OK 2400", "OK 2000",
        "OK 2400", "pin 9 2000", "pin 10 2400", "pin 11 1500", "pin 12 1500"]
    build_arduino_sketch(tmp_path, "-DBRIDGE_ARDUINO_ANALOG")  # the analogWrite glue compiles


DEAF_WATCHDOG_MS = 300
DEAF_MARGIN_S = 0.3  # scheduling slack on a loaded machine
SIGTERM_DEADLINE_S = 1.0


def _write_unread(fd: int, data: bytes, deadline_s: float) -> float | None:
    """Write `data` to a non-blocking fd, reading nothing back: the time the last byte went
    in, or None if the other end stopped taking bytes for `deadline_s`."""
    os.set_blocking(fd, False)
    view = memoryview(data)
    while view:
        if not select.select([], [fd], [], deadline_s)[1]:
            return None
        try:
            view = view[os.write(fd, view):]
        except BlockingIOError:
            continue
    return time.monotonic()


def test_a_peer_that_does_not_read_cannot_stop_the_watchdog_or_sigterm(host_binary, tmp_path):
    """Issue 49: after `SET 1 700`, a peer wrote 50,000 `GET 1` lines and read nothing. The
    host build blocked in write() of a reply: the watchdog never tripped, channel 1 stayed at
    700, and only SIGKILL ended it. Now what nobody reads is lost, as on a UART."""
    served = serve_host(host_binary, tmp_path, "--watchdog-ms", str(DEAF_WATCHDOG_MS))
    try:
        fd = os.open(served.pty_path, os.O_RDWR | os.O_NOCTTY)
        try:
            tty.setraw(fd)
            assert exchange(fd, b"SET 1 700\n") == b"OK 700\n"
            last_line = _write_unread(fd, b"GET 1\n" * 50_000, deadline_s=5.0)
            assert last_line is not None, "the firmware stopped reading its input"
            deadline = last_line + DEAF_WATCHDOG_MS / 1000 + DEAF_MARGIN_S
            while time.monotonic() < deadline and not any(
                    r[2:] == ["1", "0", "watchdog"] for r in served.trace_lines()):
                time.sleep(0.01)
            trips = [r for r in served.trace_lines() if r[2:] == ["1", "0", "watchdog"]]
            assert trips, served.trace_lines()
            # the trace is stamped on CLOCK_MONOTONIC in ms, as time.monotonic() on Linux
            assert int(trips[0][0]) / 1000 <= deadline
            sent = time.monotonic()
            served.proc.terminate()
            assert served.proc.wait(timeout=SIGTERM_DEADLINE_S) == 0
            assert time.monotonic() - sent <= SIGTERM_DEADLINE_S
            assert ["1", "0", "exit"] in [r[2:] for r in served.trace_lines()]
        finally:
            os.close(fd)
    finally:
        served.stop()
