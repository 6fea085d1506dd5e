"""Cost as runs grow: sweep, calibrate, report, Parquet export and merge of runs of 0.1 and
1.2 million samples (with --big: 1.2, 12 and 75 million, the last a 3-hour run at 7 kHz),
each command a process, with its wall time and peak memory, and the bare pass timed in the
same run.

The sweep is `rigtool sweep --sim` of a 400-point protocol on the twin (more samples per
point as the run grows; skipped above --max-sweep samples, 1.2 M by default, said so). The
other commands work on the synthetic Luo-style sweep of bench_calibrate.py (400 points),
written through the Store (at 75 M without its five all-zero F/T channels, to keep the disk
use at ~5 GB); merge copies the run into an empty database. The bare pass reads each point's four channels
(`sample_arrays(run, steps=[i])`), averages the second half and fits thrust ~ C|n|n per
direction; its time is taken inside its process (no start-up), calibrate's is the whole
process. For each size the script prints time and peak RSS per command; between sizes the
marginal cost per added sample; then the issue's ratios with PASS/FAIL:
calibrate's peak RSS at the largest size <= 1.3 x at 1.2 M and < 600 MB; calibrate at
12 M and at 75 M <= 4 x the bare pass, in wall time and in CPU seconds.

    python benchmarks/bench_scaling.py [--big] [--sizes 1.2e6,12e6] [--dir DIR]
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from bench_calibrate import build_run  # noqa: E402

from rigtool.store import Store  # noqa: E402

POINTS = 400
RATIO = 4.0  # calibrate against the bare pass, wall and CPU, at 12 M and 75 M (issue 51)
LEAN_FROM = 50_000_000  # runs this large are built without the all-zero F/T channels
RUNNER = ("import resource, sys; from rigtool.cli import main; rc = main(sys.argv[1:]); "
          "u = resource.getrusage(resource.RUSAGE_SELF); "
          "print(u.ru_maxrss, u.ru_utime + u.ru_stime, file=sys.stderr); sys.exit(rc)")
BARE_PASS = """\
import resource, sys, time
import numpy as np
from rigtool.store import Store
t0, c0 = time.perf_counter(), time.process_time()
with Store(sys.argv[1], read_only=True) as store:
    run = store.resolve_run_id("last")
    n, f = [], []
    for i in store.points(run)["step_idx"]:
        s = store.sample_arrays(run, ("t_s", "thrust_n", "speed_rpm", "current_a"), steps=[i])
        half = s["t_s"].size // 2
        n.append(np.mean(s["speed_rpm"][half:]))
        f.append(np.mean(s["thrust_n"][half:]))
n, f = np.array(n), np.array(f)
for side in (n > 0, n < 0):
    x = np.abs(n[side]) * n[side]
    c = float(x @ f[side] / (x @ x))
u = resource.getrusage(resource.RUSAGE_SELF)
print(time.perf_counter() - t0, u.ru_maxrss, time.process_time() - c0, file=sys.stderr)
"""
SWEEP_PROTOCOL = """\
rigtool_protocol: 1
name: scaling-{n}
simulator: {{profile: can-bldc, seed: 7}}
command: {{unit: percent, range: {{start: -100, stop: 99.5, step: 0.5}}}}
depth: {{unit: m, values: [1.0]}}
timing:
  settle: {{seconds: 0.2}}
  acquire: {{samples: {per_point}, rate_hz: 10000}}
  rest_s: 0
  tare: at_start
limits: {{max_thrust_n: 200}}
"""
COMMANDS = {  # the ratios' commands first: on a slow machine the rest may not be waited for
    "calibrate": ["calibrate", "last", "--out", "{tmp}/cal", "--db", "{db}"],
    "merge": ["merge", "{db}", "-o", "{tmp}/merged{n}.sqlite"],
    "report": ["report", "last", "--out", "{tmp}/cal", "--db", "{db}"],
    "export": ["export", "last", "--format", "parquet", "--out", "{tmp}/exp", "--db", "{db}"],
    "sweep": ["sweep", "{tmp}/scaling-{n}.yaml", "--sim", "--db", "{tmp}/sweep{n}.sqlite"],
}


CPU: dict[tuple[int, str], float] = {}  # CPU seconds (user + system) by (size, command)


def _run(args: list[str], key: tuple[int, str]) -> tuple[float, float]:
    """(wall seconds, peak RSS in MB) of one rigtool command in its own process (its CPU
    seconds go to CPU: on a loaded machine they tell more than the wall time)."""
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", RUNNER, *args], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if out.returncode:
        raise SystemExit(f"rigtool {' '.join(args)} failed:\n{out.stderr[-2000:]}")
    rss, cpu = out.stderr.strip().splitlines()[-1].split()
    CPU[key] = float(cpu)
    return wall, int(rss) / 1024.0


def _bare_pass(db: Path, n: int) -> tuple[float, float]:
    """(seconds inside the process, peak RSS in MB) of the bare pass over the last run."""
    out = subprocess.run([sys.executable, "-c", BARE_PASS, str(db)], capture_output=True,
                         text=True, check=True)
    seconds, rss, cpu = out.stderr.strip().splitlines()[-1].split()
    CPU[n, "bare pass"] = float(cpu)
    return float(seconds), int(rss) / 1024.0


def _size(text: str) -> int:
    return int(float(text))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--big", action="store_true",
                        help="1.2, 12 and 75 M samples (tens of minutes, ~15 GB of disk)")
    parser.add_argument("--sizes", help="comma-separated sample counts instead (e.g. 1.2e6,12e6)")
    parser.add_argument("--max-sweep", type=_size, default=1_200_000,
                        help="largest run swept on the twin (default 1.2e6)")
    parser.add_argument("--dir", type=Path, help="keep the built runs here and reuse them")
    args = parser.parse_args()
    sizes = ([_size(s) for s in args.sizes.split(",")] if args.sizes else
             [1_200_000, 12_000_000, 75_000_000] if args.big else [100_000, 1_200_000])
    results: dict[int, dict[str, tuple[float, float] | None]] = {}
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        keep = args.dir or Path(tmp)
        for n in sizes:
            db = keep / f"run{n}.sqlite"
            if not db.exists():
                t0 = time.perf_counter()
                lean = n >= LEAN_FROM
                with Store(db) as store:
                    build_run(store, POINTS, n // POINTS, rate=7000.0 if lean else 1000.0,
                              lean=lean)
                print(f"built {n / 1e6:g} M samples in {time.perf_counter() - t0:.0f} s",
                      flush=True)
            Path(tmp, f"scaling-{n}.yaml").write_text(
                SWEEP_PROTOCOL.format(n=n, per_point=n // POINTS))
            row: dict[str, tuple[float, float] | None] = {}
            for name, cmd in COMMANDS.items():
                if name == "sweep" and n > args.max_sweep:
                    row[name] = None
                    continue
                row[name] = _run([a.format(tmp=tmp, n=n, db=db) for a in cmd], (n, name))
                print(f"   {n / 1e6:g} M {name}: {row[name][0]:.2f} s, {row[name][1]:.0f} MB, "
                      f"{CPU[n, name]:.2f} CPU s", flush=True)
                if name == "calibrate":
                    row["bare pass"] = _bare_pass(db, n)
                    print(f"   {n / 1e6:g} M bare pass: {row['bare pass'][0]:.2f} s, "
                          f"{CPU[n, 'bare pass']:.2f} CPU s", flush=True)
                for leftover in (Path(tmp) / f"merged{n}.sqlite", Path(tmp) / "exp",
                                 Path(tmp) / f"sweep{n}.sqlite"):
                    if name in ("merge", "export", "sweep"):
                        shutil.rmtree(leftover, ignore_errors=True) if leftover.is_dir() \
                            else leftover.unlink(missing_ok=True)
            results[n] = row
            print(f"{n / 1e6:5.1f} M samples: " + "  ".join(
                f"{k} {'skipped (too long on the twin)' if v is None else f'{v[0]:6.2f} s {v[1]:6.0f} MB'}"
                for k, v in row.items()), flush=True)
            print("      CPU seconds: " + "  ".join(f"{k} {v:.2f}" for (m, k), v in CPU.items()
                                                    if m == n), flush=True)
    for a, b in zip(sizes, sizes[1:], strict=False):
        added = b - a
        parts = []
        for name in (*COMMANDS, "bare pass"):
            if results[a][name] is None or results[b][name] is None:
                continue
            (ta, ma), (tb, mb) = results[a][name], results[b][name]  # type: ignore[misc]
            parts.append(f"{name} {1e6 * (tb - ta) / added:5.2f} s/M samples, "
                         f"{(mb - ma) * 2**20 / added:5.0f} B/sample")
        print(f"{a / 1e6:g} -> {b / 1e6:g} M, marginal: " + "; ".join(parts))
    return _verdicts(results)


def _verdicts(results: dict[int, dict[str, tuple[float, float] | None]]) -> int:
    """Print the issue's ratios with PASS/FAIL (those the sizes measured allow)."""
    failed = 0

    def verdict(ok: bool, text: str) -> None:
        nonlocal failed
        failed += not ok
        print(f"{'PASS' if ok else 'FAIL'}: {text}")

    cal = {n: r["calibrate"] for n, r in results.items()}
    top = max(results)
    if 1_200_000 in cal and top > 1_200_000:
        small, big = cal[1_200_000][1], cal[top][1]  # type: ignore[index]
        verdict(big <= 1.3 * small, f"calibrate peak RSS at {top / 1e6:g} M {big:.0f} MB = "
                f"{big / small:.2f} x at 1.2 M ({small:.0f} MB) (goal <= 1.3 x)")
        verdict(big < 600, f"calibrate peak RSS at {top / 1e6:g} M {big:.0f} MB (goal < 600 MB)")
    for n in (12_000_000, 75_000_000):
        if n not in results:
            continue
        wall, bare = cal[n][0], results[n]["bare pass"][0]  # type: ignore[index]
        cpu, cpu_bare = CPU[n, "calibrate"], CPU[n, "bare pass"]
        verdict(wall <= RATIO * bare, f"calibrate at {n / 1e6:g} M {wall:.2f} s (whole process) = "
                f"{wall / bare:.1f} x the bare pass {bare:.2f} s (goal <= {RATIO:g} x)")
        verdict(cpu <= RATIO * cpu_bare, f"calibrate at {n / 1e6:g} M {cpu:.2f} CPU s (whole "
                f"process) = {cpu / cpu_bare:.1f} x the bare pass's {cpu_bare:.2f} "
                f"(goal <= {RATIO:g} x)")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
