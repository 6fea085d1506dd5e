"""Benchmark: the wall time of the whole test suite, as CI runs it, with the machine's load.

Runs `python -m pytest -q` (plus any extra pytest arguments) in the repository as a child
process and prints its wall time, the CPU time of every process it started (user + system,
from getrusage of the children) and the load average before and after. On a shared machine
the wall time alone says little; the CPU time divided by the cores approximates an idle run.

    python benchmarks/bench_suite.py [--per-file N] [PYTEST ARGS...]   e.g. -n 0 for one process

With --per-file N it also prints the N test files that took the most CPU (each test's process
and the processes it waited for; summed over the file's tests; plugin benchmarks/suite_cpu.py).
"""

from __future__ import annotations

import collections
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def main(argv: list[str]) -> int:
    """Run the suite once and print its times; exit with pytest's status."""
    top = 0
    if argv[:1] == ["--per-file"]:
        top, argv = int(argv[1]), argv[2:]
    records = tempfile.TemporaryDirectory()
    env = dict(os.environ)
    if top:
        env["SUITE_CPU_DIR"] = records.name
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT / "benchmarks"),
                                                          env.get("PYTHONPATH")]))
        argv = ["-p", "suite_cpu", *argv]
    load_before = os.getloadavg()
    t0 = time.perf_counter()
    status = subprocess.call([sys.executable, "-m", "pytest", "-q", *argv], cwd=ROOT, env=env)
    wall_s = time.perf_counter() - t0
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu_s = usage.ru_utime + usage.ru_stime
    cores = os.cpu_count() or 1
    print(f"suite: exit {status}, wall {wall_s:.1f} s, CPU {cpu_s:.1f} s "
          f"(user {usage.ru_utime:.1f} s, system {usage.ru_stime:.1f} s) on {cores} cores, "
          f"load average {load_before[0]:.2f} before, {os.getloadavg()[0]:.2f} after")
    if top:
        _print_per_file(Path(records.name), top)
    records.cleanup()
    return status


def _print_per_file(folder: Path, top: int) -> None:
    """The `top` test files by CPU seconds, with their wall seconds and share of the total."""
    cpu: dict[str, float] = collections.Counter()
    wall: dict[str, float] = collections.Counter()
    for path in folder.glob("*.json"):
        for nodeid, (cpu_s, wall_s) in json.loads(path.read_text()).items():
            cpu[nodeid.split("::")[0]] += cpu_s
            wall[nodeid.split("::")[0]] += wall_s
    total = sum(cpu.values())
    print(f"per test file: {len(cpu)} files, {total:.0f} CPU s in tests "
          f"({sum(1 for v in cpu.values() if v < 10)} files under 10 s)")
    for name, cpu_s in sorted(cpu.items(), key=lambda kv: -kv[1])[:top]:
        print(f"  {cpu_s:7.1f} CPU s {wall[name]:7.1f} wall s {100 * cpu_s / total:5.1f} %  {name}")


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
