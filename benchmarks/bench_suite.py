"""Benchmark: the wall time of the whole test suite, as CI runs it, with the machine's load.

Runs `python -m pytest -q` (plus any extra pytest arguments) in the repository as a child
process and prints its wall time, the CPU time of every process it started (user + system,
from getrusage of the children) and the load average before and after. On a shared machine
the wall time alone says little; the CPU time divided by the cores approximates an idle run.

    python benchmarks/bench_suite.py [PYTEST ARGS...]      e.g. -n 0 for one process
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def main(argv: list[str]) -> int:
    """Run the suite once and print its times; exit with pytest's status."""
    load_before = os.getloadavg()
    t0 = time.perf_counter()
    status = subprocess.call([sys.executable, "-m", "pytest", "-q", *argv], cwd=ROOT)
    wall_s = time.perf_counter() - t0
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu_s = usage.ru_utime + usage.ru_stime
    cores = os.cpu_count() or 1
    print(f"suite: exit {status}, wall {wall_s:.1f} s, CPU {cpu_s:.1f} s "
          f"(user {usage.ru_utime:.1f} s, system {usage.ru_stime:.1f} s) on {cores} cores, "
          f"load average {load_before[0]:.2f} before, {os.getloadavg()[0]:.2f} after")
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
