"""Benchmark: `rigtool report` against `rigtool calibrate` of the same run, as whole processes.

The report renders what calibrate stored and recomputes nothing, so it should take at most
half of calibrate's time (issue: "rigtool as a library"). Sweeps the shipped protocols on the
simulator into a temporary database (luo2020-cavitation with its deep base run gives the
quasi-cavitation stage), then times, interleaved, `calibrate` and `report` of each run
`--repeats` times and prints the medians and the ratio report / calibrate.

    python benchmarks/bench_report.py [--repeats 3] [--only esc-1100-1900]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# (protocol, runs swept before it that it needs: the cavitation run's deep base run)
CASES = {
    "luo2020-baseline": [],
    "esc-1100-1900": [],
    "quick-demo": [],
    "luo2020-cavitation": ["luo2020-baseline"],
}
TARGET = 0.5


def _rigtool(*args: str, env: dict) -> float:
    """Run one rigtool command as a process; its wall time (s)."""
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "rigtool", *args], env=env, check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--only", choices=sorted(CASES))
    args = parser.parse_args()
    worst = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, RIGTOOL_DB=str(Path(tmp) / "bench.sqlite"))
        out = str(Path(tmp) / "cal")
        for name, before in CASES.items():
            if args.only and name != args.only:
                continue
            for protocol in [*before, name]:
                _rigtool("sweep", str(ROOT / "protocols" / f"{protocol}.yaml"), "--sim", env=env)
            cal, rep = [], []
            for _ in range(args.repeats):
                cal.append(_rigtool("calibrate", "last", "--out", out, env=env))
                rep.append(_rigtool("report", "last", "--out", out, env=env))
            c, r = statistics.median(cal), statistics.median(rep)
            worst = max(worst, r / c)
            print(f"{name:20s} calibrate {c:6.2f} s  report {r:6.2f} s  "
                  f"report/calibrate {r / c:.2f} (target <= {TARGET})")
    print(f"worst ratio {worst:.2f}: {'met' if worst <= TARGET else 'NOT met'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
