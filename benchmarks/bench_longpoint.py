"""Calibrate's memory with one very long point: an endurance dwell of 1.2 M and 25 M samples
(25 M: one hour at the Net F/T's 7 kHz) after a 40-point sweep, each calibrated as a process.

Each run is built directly in the Store (as bench_scaling.py builds its runs): 40 points of
3000 samples from -100 to 100 %, then the dwell at 60 % (thrust, speed, current, voltage,
command, fx; the other F/T channels not recorded), written through a SampleSpool one
million samples at a time so the build itself stays small. `rigtool calibrate` of each run
runs in its own process: wall time, CPU seconds and peak RSS. Goals (issue 51): the peak at
25 M <= 1.3 x the peak at 1.2 M, and under 600 MB.

    python benchmarks/bench_longpoint.py [--sizes 1.2e6,25e6] [--dir DIR]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import rigtool
from rigtool.spool import SampleSpool
from rigtool.store import SAMPLE_COLUMNS, STAT_FIELDS, StepRecord, Store

SWEEP_POINTS, SWEEP_SAMPLES, DWELL_COMMAND = 40, 3000, 60.0
RATE = 7000.0
PIECE = 1_000_000  # samples generated and spooled at a time
RUNNER = ("import resource, sys; from rigtool.cli import main; rc = main(sys.argv[1:]); "
          "u = resource.getrusage(resource.RUSAGE_SELF); "
          "print(u.ru_maxrss, u.ru_utime + u.ru_stime, file=sys.stderr); sys.exit(rc)")


def _samples(rng: np.random.Generator, command: float, t0: float, start: int,
             n: int) -> dict[str, np.ndarray]:
    """`n` samples from sample `start` of a point held at `command` from time `t0`."""
    tt = (start + np.arange(n)) / RATE
    target = 1800.0 * command / 100.0
    speed = target * (1 - np.exp(-(tt + 0.05) / 0.2)) + rng.normal(0, 2, n)
    cp = np.where(speed >= 0, 1.926e-5, 0.8 * 1.926e-5)
    thrust = cp * np.abs(speed) * speed + rng.normal(0, 0.25, n) + 0.1 * np.sin(62.8 * tt)
    current = 1.2e-9 * np.abs(speed) ** 3 + 0.3 + rng.normal(0, 0.05, n)
    return {"t_s": t0 + tt, "fx": -thrust, "thrust_n": thrust, "speed_rpm": speed,
            "current_a": current, "voltage_v": 48.0 + rng.normal(0, 0.05, n),
            "command": np.full(n, command)}


def build(store: Store, dwell: int, spill: Path) -> str:
    """The sweep then the dwell of `dwell` samples, written through the Store."""
    rng = np.random.default_rng(51)
    run_id = store.create_run(name=f"longpoint-{dwell}", protocol={"command": {"unit": "percent"}},
                              protocol_path=None, rig={}, plan=[], metadata={}, seed=51,
                              command_unit="percent", tool_version=rigtool.__version__)
    store.add_event(run_id, "tare", {"bias": [0.4, 0, 0, 0, 0, 0]}, t_s=0.0)
    t = 0.0
    commands = [*np.linspace(-100.0, 100.0, SWEEP_POINTS), DWELL_COMMAND]
    for i, c in enumerate(commands):
        n = dwell if i == SWEEP_POINTS else SWEEP_SAMPLES
        spool = SampleSpool(SAMPLE_COLUMNS[1:], STAT_FIELDS, spill_dir=spill)
        for start in range(0, n, PIECE):
            spool.add(_samples(rng, float(c), t + 0.5, start, min(PIECE, n - start)))
        step = StepRecord(i, float(c), "percent", None, 0, "up", t, t + 0.5,
                          t + 0.5 + n / RATE, 0.5, True, RATE)
        store.add_step(run_id, step, spool)
        spool.close()
        t += 0.5 + n / RATE
    store.finish_run(run_id, "completed")
    return run_id


def calibrate(db: Path, out: Path) -> tuple[float, float, float]:
    """(wall s, CPU s, peak RSS MB) of `rigtool calibrate last` as a process."""
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", RUNNER, "calibrate", "last", "--db", str(db),
                           "--out", str(out)], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode:
        raise SystemExit(f"calibrate of {db} failed:\n{proc.stderr[-2000:]}")
    rss, cpu = proc.stderr.strip().splitlines()[-1].split()
    return wall, float(cpu), int(rss) / 1024.0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="1.2e6,25e6",
                        help="dwell lengths in samples, the first the reference (default 1.2e6,25e6)")
    parser.add_argument("--dir", type=Path, help="keep the built runs here and reuse them")
    args = parser.parse_args()
    sizes = [int(float(s)) for s in args.sizes.split(",")]
    peaks = {}
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        keep = args.dir or Path(tmp)
        for n in sizes:
            db = keep / f"longpoint{n}.sqlite"
            if not db.exists():
                t0 = time.perf_counter()
                with Store(db) as store:
                    build(store, n, Path(tmp))
                print(f"built a {n / 1e6:g} M-sample dwell in {time.perf_counter() - t0:.0f} s",
                      flush=True)
            wall, cpu, rss = calibrate(db, Path(tmp) / f"cal{n}")
            peaks[n] = rss
            print(f"dwell {n / 1e6:5.1f} M samples: calibrate {wall:6.1f} s, {cpu:6.1f} CPU s, "
                  f"peak RSS {rss:5.0f} MB", flush=True)
    small, big = peaks[sizes[0]], peaks[sizes[-1]]
    ok_ratio, ok_abs = big <= 1.3 * small, big < 600
    print(f"{'PASS' if ok_ratio else 'FAIL'}: peak at {sizes[-1] / 1e6:g} M {big:.0f} MB = "
          f"{big / small:.2f} x at {sizes[0] / 1e6:g} M ({small:.0f} MB) (goal <= 1.3 x)")
    print(f"{'PASS' if ok_abs else 'FAIL'}: peak at {sizes[-1] / 1e6:g} M {big:.0f} MB "
          "(goal < 600 MB)")
    return 0 if ok_ratio and ok_abs else 1


if __name__ == "__main__":
    sys.exit(main())
