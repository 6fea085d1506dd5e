"""Peak memory of report, export, import and merge as runs grow: each command a process, its
peak RSS (ru_maxrss) and wall time, at two run sizes.

The stored run is the synthetic 400-point Luo-style sweep of bench_calibrate.py, written
through the Store and calibrated once (report reads what calibrate stored). The import log is
a Tyto-style time series CSV (time, command, thrust, speed, current, voltage) of the same
number of rows, one command level per 1/400 of it. Memory bounded by the point shows as the
same peak at both sizes; a per-row cost as the marginal bytes per sample printed last.

    python benchmarks/bench_memory.py [--sizes 1200000 12000000] [--only report export-csv ...]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from bench_calibrate import build_run  # noqa: E402

from rigtool.store import Store  # noqa: E402

POINTS = 400
RUNNER = ("import resource, sys; from rigtool.cli import main; rc = main(sys.argv[1:]); "
          "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr); "
          "sys.exit(rc)")
COMMANDS = {
    "report": ["report", "last", "--out", "{tmp}/cal{n}", "--db", "{db}"],
    "export-parquet": ["export", "last", "--format", "parquet", "--out", "{tmp}/pq{n}",
                       "--db", "{db}"],
    "export-csv": ["export", "last", "--format", "csv", "--out", "{tmp}/csv{n}", "--db", "{db}"],
    "merge": ["merge", "{db}", "-o", "{tmp}/merged{n}.sqlite"],
    "import": ["import", "{tmp}/log{n}.csv", "--format", "timeseries", "--db",
               "{tmp}/imported{n}.sqlite"],
}
NEEDS_CSV_LOG = ("import",)


def run_command(args: list[str]) -> tuple[float, float]:
    """(wall seconds, peak RSS in MB) of one rigtool command in its own process."""
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", RUNNER, *args], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if out.returncode != 0:
        raise SystemExit(f"rigtool {' '.join(args)} failed ({out.returncode}):\n{out.stderr}")
    return wall, int(out.stderr.strip().splitlines()[-1]) / 1024.0


def write_log(path: Path, n_rows: int, seed: int = 3) -> None:
    """A Tyto-style time series log of `n_rows` rows at 1 kHz, 400 command levels, in chunks."""
    rng = np.random.default_rng(seed)
    per = max(n_rows // POINTS, 1)
    commands = np.linspace(1100.0, 1900.0, POINTS)
    with path.open("w", encoding="utf-8") as fh:
        fh.write("Time (s),ESC signal (µs),Thrust (N),Motor Electrical Speed (RPM),"
                 "Current (A),Voltage (V)\n")
        for i, c in enumerate(commands):
            t = (i * per + np.arange(per)) / 1000.0
            n = 30.0 * (c - 1500.0) + rng.normal(0, 5, per)
            thrust = 1.9e-5 * np.abs(n) * n + rng.normal(0, 0.2, per)
            current = 1e-9 * np.abs(n) ** 3 + 0.3 + rng.normal(0, 0.05, per)
            block = np.column_stack([t, np.full(per, c), thrust, n, current, np.full(per, 16.0)])
            np.savetxt(fh, block, fmt=["%.4f", "%.0f", "%.5f", "%.2f", "%.4f", "%.2f"],
                       delimiter=",")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1_200_000, 12_000_000])
    parser.add_argument("--only", nargs="+", choices=list(COMMANDS), default=list(COMMANDS))
    parser.add_argument("--tmp", type=Path, default=None, help="work folder (kept)")
    args = parser.parse_args()
    results: dict[int, dict[str, tuple[float, float]]] = {}
    with tempfile.TemporaryDirectory() as scratch:
        tmp = args.tmp or Path(scratch)
        tmp.mkdir(parents=True, exist_ok=True)
        for n in args.sizes:
            db = tmp / f"run{n}.sqlite"
            if not db.exists():
                with Store(db) as store:
                    build_run(store, POINTS, n // POINTS)
                run_command(["calibrate", "last", "--out", f"{tmp}/cal{n}", "--db", str(db)])
            if any(c in NEEDS_CSV_LOG for c in args.only) and not (tmp / f"log{n}.csv").exists():
                write_log(tmp / f"log{n}.csv", n)
            results[n] = {}
            for name in args.only:
                (tmp / f"merged{n}.sqlite").unlink(missing_ok=True)
                (tmp / f"imported{n}.sqlite").unlink(missing_ok=True)
                cmd = [a.format(tmp=tmp, n=n, db=db) for a in COMMANDS[name]]
                results[n][name] = run_command(cmd)
                t, m = results[n][name]
                print(f"{n / 1e6:5.1f} M samples  {name:15s} {t:7.2f} s {m:7.0f} MB", flush=True)
    for a, b in zip(args.sizes, args.sizes[1:], strict=False):
        added = b - a
        parts = [f"{name} {(results[b][name][1] - results[a][name][1]) * 2**20 / added:6.1f}"
                 for name in args.only]
        print(f"{a / 1e6:g} -> {b / 1e6:g} M, marginal bytes per sample: " + "; ".join(parts))
    return 0


if __name__ == "__main__":
    sys.exit(main())
