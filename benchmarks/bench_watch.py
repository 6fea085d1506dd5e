"""Benchmark: what a watcher costs a live 7 kHz sweep over real transports.

Starts `rigtool sim` (STM32 bridge over TCP, Net F/T over UDP) at `--rate`, then runs the
bench_realtime protocol as a `rigtool sweep --rig` process three ways, in one run: alone
(the baseline), with `rigtool watch` in its own process polled for /data once a second the
way the page polls, and with `--watch` (the server in a child process the sweep starts and
waits for, so its CPU counts with the sweep's; polled the same way). Reports the sweep
process's CPU (% of one core) in each, the rise over the baseline and the ratio, and samples
lost (sequence gaps, lost packets). The target: a
watcher raises the sweep's CPU by less than 1 % of a core and loses nothing.

    python benchmarks/bench_watch.py [--minutes 1] [--rate 7000] [--rounds 2]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

from bench_realtime import POINT_S, PROTOCOL, losses, start_sim

from rigtool.store import Store

TARGET_RISE = 1.0  # % of a core


def _poll(url: str, stop: threading.Event, counts: list[int]) -> None:
    """GET /data once a second until `stop`, like the page."""
    while not stop.wait(1.0):
        try:
            with urllib.request.urlopen(url + "data", timeout=10) as resp:
                json.loads(resp.read())
                counts[0] += 1
        except OSError:
            counts[1] += 1


def _url(proc: subprocess.Popen) -> str:
    for line in proc.stderr:
        m = re.search(r"(http://127\.0\.0\.1:\d+/)", line)
        if m:
            return m.group(1)
    raise SystemExit("no watch address printed")


def _has_run(db: Path) -> bool:
    try:
        with Store(db, read_only=True) as store:
            store.resolve_run_id("last")
        return True
    except Exception:  # noqa: BLE001 - not created yet
        return False


def run(root: Path, rig: Path, rate: float, minutes: float, mode: str, tag: str
        ) -> tuple[float, float, int, Path, list[int]]:
    """One sweep process; (wall s, CPU s, exit code, db, [polls ok, polls failed])."""
    repeats = max(1, round(minutes * 60 / POINT_S / 5))
    protocol = root / f"p-{tag}.yaml"
    protocol.write_text(PROTOCOL.format(rate=rate, repeats=repeats))
    db = root / f"{tag}.sqlite"
    extra = ["--watch", "0"] if mode == "--watch" else []
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-m", "rigtool", "sweep", str(protocol), "--rig",
                             str(rig), "--db", str(db), *extra],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    stop, counts, watch = threading.Event(), [0, 0], None
    poller = None
    if mode != "alone":
        if mode == "--watch":
            url = _url(proc)
        else:
            while not _has_run(db):
                time.sleep(0.05)
            watch = subprocess.Popen([sys.executable, "-m", "rigtool", "watch", "--db", str(db),
                                      "--port", "0"], stdin=subprocess.DEVNULL,
                                     stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
            url = _url(watch)
        poller = threading.Thread(target=_poll, args=(url, stop, counts), daemon=True)
        poller.start()
    drain = threading.Thread(target=proc.stderr.read, daemon=True)
    drain.start()
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.monotonic() - t0
    stop.set()
    if poller is not None:
        poller.join()
    if watch is not None:
        watch.terminate()
        watch.wait(timeout=10)
    return wall, usage.ru_utime + usage.ru_stime, os.waitstatus_to_exitcode(status), db, counts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=1.0, help="length of each sweep")
    parser.add_argument("--rate", type=float, default=7000.0)
    parser.add_argument("--rounds", type=int, default=2, help="alternations of the three modes")
    args = parser.parse_args()
    modes = ("alone", "watch process", "--watch")
    results: dict[str, list[float]] = {m: [] for m in modes}
    print(f"{'mode':>14} {'wall':>6} {'CPU':>6} {'% core':>7} {'points':>6} {'samples':>9} "
          f"{'gaps':>5} {'lost':>5} {'polls':>5} exit")
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        sim, rig = start_sim(root, args.rate)
        try:
            for r in range(args.rounds):
                for mode in modes if r % 2 == 0 else reversed(modes):
                    tag = f"{mode.replace(' ', '-')}-{r}"
                    wall, cpu, code, db, polls = run(root, rig, args.rate, args.minutes, mode, tag)
                    points, stored, gaps, lost = losses(db)
                    percent = 100 * cpu / wall
                    results[mode].append(percent)
                    print(f"{mode:>14} {wall:5.0f}s {cpu:5.1f}s {percent:6.2f}% {points:6d} "
                          f"{stored:9,d} {gaps:5d} {lost:5d} {polls[0]:5d} {code}", flush=True)
        finally:
            sim.terminate()
            sim.wait(timeout=10)
    base = sum(results["alone"]) / len(results["alone"])
    for mode in modes[1:]:
        mean = sum(results[mode]) / len(results[mode])
        rise = mean - base
        print(f"{mode}: sweep CPU {mean:.2f} % vs {base:.2f} % alone: rise {rise:+.2f} % of a "
              f"core, ratio {mean / base:.3f} (target rise < {TARGET_RISE:g} %: "
              f"{'met' if rise < TARGET_RISE else 'NOT met'})")


if __name__ == "__main__":
    main()
