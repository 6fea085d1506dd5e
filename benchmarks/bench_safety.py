"""Command-to-neutral latency on the twin over real transports (figures for docs/safety.md).

1. driver: `neutral()` called -> the twin's thruster at neutral, over a pty and TCP
   (STM32 bridge) and a python-can bus (VESC).
2. signal: SIGTERM / Ctrl-C sent to a sweep process -> the twin at neutral (the sweep
   runs as a separate process against an in-process bridge twin on TCP).
3. watchdog: sweep process killed with SIGKILL (no neutral from the host) -> the
   bridge firmware's watchdog puts the twin at neutral.

    python benchmarks/bench_safety.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

from rigtool.devices.stm32_bridge import Stm32Bridge, Stm32BridgeConfig
from rigtool.devices.vesc_can import VescCanConfig, VescCanDriver
from rigtool.sim.live import LiveTwin
from rigtool.sim.netft_twin import NetFTTwin
from rigtool.sim.physics import ThrusterTwin
from rigtool.sim.stm32_twin import Stm32BridgeTwin
from rigtool.sim.vesc_twin import VescTwin
from rigtool.thruster_profiles import PROFILES

POLL_S = 0.0002


def _wait_neutral(live: LiveTwin, timeout: float = 5.0) -> float:
    neutral = live.twin.profile.neutral
    t0 = time.perf_counter()
    while live.command != neutral:
        if time.perf_counter() - t0 > timeout:
            raise TimeoutError("twin never reached neutral")
        time.sleep(POLL_S)
    return time.perf_counter()


def _wait_running(live: LiveTwin, timeout: float = 30.0) -> None:
    t0 = time.perf_counter()
    while live.command == live.twin.profile.neutral:
        if time.perf_counter() - t0 > timeout:
            raise TimeoutError("twin never left neutral")
        time.sleep(0.001)


def driver_latency(kind: str, repeats: int) -> list[float]:
    profile = "can-bldc" if kind == "can" else "stm32-pwm"
    live = LiveTwin(ThrusterTwin(PROFILES[profile], seed=1)).start()
    if kind == "can":
        twin = VescTwin(live, channel=f"bench-{os.getpid()}").start()
        driver = VescCanDriver(VescCanConfig(driver="vesc-can", interface="virtual",
                                             channel=twin.channel))
        command = 50.0
    else:
        twin = Stm32BridgeTwin(live).start()
        url = twin.pty_path if kind == "pty" else twin.url
        driver = Stm32Bridge(Stm32BridgeConfig(driver="stm32-bridge", url=url))
        command = 300.0
    out = []
    try:
        for _ in range(repeats):
            driver.set_command(command)
            _wait_running(live)
            t0 = time.perf_counter()
            driver.neutral()
            out.append(_wait_neutral(live) - t0)
    finally:
        driver.close()
        twin.stop()
        live.stop()
    return out


PROTOCOL = """\
rigtool_protocol: 1
name: safety-bench
command: {unit: pwm_counts, values: [300, 300, 300, 300, 300, 300, 300, 300]}
depth: {unit: m, values: [0.5], mode: preset}
timing:
  settle: {seconds: 5}
  acquire: {samples: 5000, rate_hz: 1000}
  tare: never
"""


def process_latency(signals: list[int], repeats: int) -> list[float]:
    """Signal a sweep process mid-point; time from the last signal until the twin is at neutral."""
    out = []
    live = LiveTwin(ThrusterTwin(PROFILES["stm32-pwm"], seed=1)).start()
    bridge = Stm32BridgeTwin(live, watchdog_ms=300).start()
    ft = NetFTTwin(live).start()
    try:
        with tempfile.TemporaryDirectory() as tmp:
            host, port = ft.address
            rig = {"name": "bench", "actuator": {"driver": "stm32-bridge", "url": bridge.url,
                                                  "watchdog_ms": 300},
                   "sensor": {"driver": "ati-netft", "host": host, "port": port,
                              "http_port": ft.http_port},
                   "thrust": {"channel": "fz", "sign": -1}}
            Path(tmp, "rig.yaml").write_text(yaml.safe_dump(rig))
            Path(tmp, "p.yaml").write_text(PROTOCOL)
            for i in range(repeats):
                proc = subprocess.Popen(
                    [sys.executable, "-m", "rigtool.cli", "sweep", f"{tmp}/p.yaml", "--rig",
                     f"{tmp}/rig.yaml", "--db", f"{tmp}/r{i}.sqlite"],
                    stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                _wait_running(live)
                time.sleep(0.5)
                for sig in signals[:-1]:
                    proc.send_signal(sig)
                    time.sleep(0.05)  # separate signals: a pending signal is not queued twice
                t0 = time.perf_counter()
                proc.send_signal(signals[-1])
                out.append(_wait_neutral(live) - t0)
                proc.wait(timeout=30)
    finally:
        ft.stop()
        bridge.stop()
        live.stop()
    return out


def _fmt(name: str, values: list[float]) -> str:
    ms = [v * 1000 for v in values]
    return (f"{name:<44} median {statistics.median(ms):8.2f} ms   max {max(ms):8.2f} ms   "
            f"(n={len(ms)})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    print(_fmt("neutral(): STM32 bridge over pty", driver_latency("pty", args.repeats)))
    print(_fmt("neutral(): STM32 bridge over TCP", driver_latency("tcp", args.repeats)))
    print(_fmt("neutral(): VESC over python-can bus", driver_latency("can", args.repeats)))
    print(_fmt("SIGTERM to sweep process -> neutral", process_latency([signal.SIGTERM], args.repeats)))
    print(_fmt("Ctrl-C twice to sweep process -> neutral",
               process_latency([signal.SIGINT, signal.SIGINT], args.repeats)))
    print(_fmt("SIGKILL (host gone) -> firmware watchdog 300 ms",
               process_latency([signal.SIGKILL], args.repeats)))


if __name__ == "__main__":
    main()
