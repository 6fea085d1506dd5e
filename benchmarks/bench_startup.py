"""Benchmark: CLI start-up, `rigtool --version` and `rigtool runs --help`, as processes.

Times each command `--repeats` times, interleaved with a bare `python -c pass` as the
baseline of the same run, and prints the medians, rigtool's cost over bare Python, and
whether the start-up stays under the 0.5 s goal.

    python benchmarks/bench_startup.py [--repeats 7]
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time

GOAL_S = 0.5
COMMANDS = {
    "python -c pass (baseline)": [sys.executable, "-c", "pass"],
    "rigtool --version": [sys.executable, "-m", "rigtool", "--version"],
    "rigtool runs --help": [sys.executable, "-m", "rigtool", "runs", "--help"],
}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    times: dict[str, list[float]] = {name: [] for name in COMMANDS}
    for _ in range(args.repeats):
        for name, cmd in COMMANDS.items():
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True, capture_output=True)
            times[name].append(time.perf_counter() - t0)
    base = statistics.median(times["python -c pass (baseline)"])
    worst = 0.0
    for name, values in times.items():
        median = statistics.median(values)
        print(f"{name:28s} median {median:.3f} s (max {max(values):.3f}), "
              f"{median - base:+.3f} s over bare Python")
        if name.startswith("rigtool"):
            worst = max(worst, median)
    print(f"slowest rigtool start-up {worst:.3f} s (goal < {GOAL_S} s): "
          f"{'met' if worst < GOAL_S else 'NOT met'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
