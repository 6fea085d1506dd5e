"""Benchmark: CPU of a live sweep over real transports, and samples lost, at 1 kHz and 7 kHz.

Starts `rigtool sim` (STM32 PWM bridge over TCP, ATI Net F/T over UDP, depth stage) in its own
process at each rate, then runs `rigtool sweep --rig` on it as a second process, the way a lab
runs it, and reports that acquisition process's CPU time over its wall time (% of one core;
the simulator's own CPU is not counted), samples stored, and samples lost: gaps in the stored
sensor sequence numbers inside every point, and the driver's lost-packet counter.

Baseline, on the same simulator just before: a bare Python reader (one blocking `recv` per
datagram, nothing parsed or stored) of the same stream for `--baseline-s` seconds; the
sweep's CPU is also printed as a ratio to it.

    python benchmarks/bench_realtime.py [--minutes 10] [--rates 1000 7000] [--baseline-s 60]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

from rigtool.store import Store

PROTOCOL = """\
rigtool_protocol: 1
name: realtime-{rate:g}
command: {{unit: pwm_counts, values: [0, 300, 415, 460, 600], repeats: {repeats}}}
depth: {{unit: m, values: [1.0]}}
timing:
  settle: {{seconds: 0.5}}
  acquire: {{seconds: 1.0, rate_hz: {rate:g}}}
  rest_s: 0.2
  tare: at_start
limits: {{max_thrust_n: 20}}
"""
POINT_S = 0.5 + 1.0 + 0.2 + 0.3  # settle, acquire, rest, ramps and commit (about)
TARGET_PERCENT = 10.0
BARE_READER = """\
import socket, struct, sys, time
host, port, seconds = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
sock.connect((host, port))
sock.settimeout(5.0)
sock.send(struct.pack(">HHI", 0x1234, 2, 0))
n, end = 0, time.monotonic() + seconds
while time.monotonic() < end:
    sock.recv(4096)
    n += 1
sock.send(struct.pack(">HHI", 0x1234, 0, 0))
print(n)
"""


def start_sim(root: Path, rate: float) -> tuple[subprocess.Popen, Path]:
    rig = root / f"rig-{rate:g}.yaml"
    proc = subprocess.Popen(
        [sys.executable, "-m", "rigtool", "sim", "--profile", "stm32-pwm", "--sensor", "netft",
         "--netft", "0", "--rate", f"{rate:g}", "--rig-out", str(rig)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 30
    while not rig.exists():
        if proc.poll() is not None or time.monotonic() > deadline:
            raise SystemExit("rigtool sim did not start")
        time.sleep(0.1)
    return proc, rig


def bare_reader(rig: Path, seconds: float) -> tuple[float, int]:
    """CPU of a bare Python reader of the simulator's Net F/T stream (% of a core), and the
    datagrams it read."""
    sensor = yaml.safe_load(rig.read_text())["sensor"]
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-c", BARE_READER, sensor["host"],
                             str(sensor["port"]), str(seconds)], stdout=subprocess.PIPE)
    out = proc.stdout.read()
    _, _, usage = os.wait4(proc.pid, 0)
    wall = time.monotonic() - t0
    return 100 * (usage.ru_utime + usage.ru_stime) / wall, int(out or 0)


def sweep(root: Path, rig: Path, rate: float, minutes: float) -> tuple[float, float, int]:
    """Run the sweep process; (wall s, CPU s, exit code)."""
    repeats = max(1, round(minutes * 60 / POINT_S / 5))
    protocol = root / f"p-{rate:g}.yaml"
    protocol.write_text(PROTOCOL.format(rate=rate, repeats=repeats))
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-m", "rigtool", "sweep", str(protocol), "--rig",
                             str(rig), "--db", str(root / f"{rate:g}.sqlite")],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.monotonic() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    return wall, usage.ru_utime + usage.ru_stime, proc.returncode


def losses(db: Path) -> tuple[int, int, int]:
    """(points, samples stored, samples missing from the points' sequence numbers, packets the
    driver counted lost during points)."""
    with Store(db, read_only=True) as store:
        points = store.conn.execute("SELECT id, counters_json FROM steps ORDER BY idx").fetchall()
        stored = gaps = lost = 0
        for step_id, counters in points:
            seq = store.step_samples(step_id, ["seq"])["seq"]
            stored += seq.size
            if seq.size:
                gaps += int(seq[-1] - seq[0] + 1 - seq.size)
            lost += int((json.loads(counters or "{}").get("sensor") or {}).get("lost_packets", 0))
    return len(points), stored, gaps, lost


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--rates", type=float, nargs="+", default=[1000.0, 7000.0])
    parser.add_argument("--baseline-s", type=float, default=60.0)
    args = parser.parse_args()
    print(f"{'rate':>6} {'wall':>7} {'CPU':>7} {'% of a core':>11} {'bare reader':>11} "
          f"{'ratio':>5} {'points':>6} {'samples':>10} {'seq gaps':>8} {'lost pkts':>9} exit")
    worst = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        for rate in args.rates:
            sim, rig = start_sim(root, rate)
            try:
                bare, _ = bare_reader(rig, args.baseline_s)
                wall, cpu, code = sweep(root, rig, rate, args.minutes)
            finally:
                sim.terminate()
                sim.wait(timeout=10)
            points, stored, gaps, lost = losses(root / f"{rate:g}.sqlite")
            percent = 100 * cpu / wall
            worst = max(worst, percent)
            print(f"{rate:6g} {wall:6.0f}s {cpu:6.1f}s {percent:10.1f}% {bare:10.1f}% "
                  f"{percent / bare:5.2f} {points:6d} {stored:10,d} {gaps:8d} {lost:9d} {code}",
                  flush=True)
    print(f"worst {worst:.1f} % of a core (target < {TARGET_PERCENT:g} %): "
          f"{'met' if worst < TARGET_PERCENT else 'NOT met'}")


if __name__ == "__main__":
    main()
