"""End-to-end sweep throughput on the simulator vs a bare sqlite3 executemany of the same rows.

Runs a protocol on the twin into a fresh database (samples/s, wall time), in this process
and as a whole `rigtool sweep --sim` process; then inserts the very same samples as rows
with plain sqlite3 (the row table rigtool used up to schema v7, same pragmas, one
transaction per point as the engine commits) and prints the ratios of samples/s. All are
measured in this run, so machine noise hits them alike. rigtool itself stores column BLOBs
(schema v8), so a ratio above 1 means a whole sweep is faster than the bare row insert.

    python benchmarks/bench_sweep.py                       # full luo2020-baseline (1.2 M samples)
    python benchmarks/bench_sweep.py protocols/quick-demo.yaml --repeats 3
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from rigtool.progress import SilentReporter
from rigtool.store import Store
from rigtool.sweep import resolve, run_sweep

sys.path.insert(0, str(Path(__file__).parent))
import rowtable  # noqa: E402  (the v7 row table: the baseline)

ROOT = Path(__file__).resolve().parent.parent


def time_sweep(protocol: Path, db: Path) -> tuple[float, str]:
    setup = resolve(protocol, sim=True)
    store = Store(db)
    t0 = time.perf_counter()
    outcome = run_sweep(setup, store, SilentReporter())
    elapsed = time.perf_counter() - t0
    store.close()
    assert outcome.status == "completed", outcome
    return elapsed, outcome.run_id


def time_sweep_process(protocol: Path, db: Path) -> float:
    """Wall time of `rigtool sweep --sim` as a user runs it (interpreter start-up included)."""
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "rigtool", "sweep", str(protocol), "--sim", "--db",
                    str(db)], check=True, capture_output=True)
    return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("protocol", nargs="?", default=str(ROOT / "protocols/luo2020-baseline.yaml"))
    parser.add_argument("--repeats", type=int, default=1)
    args = parser.parse_args()
    sweep_s, process_s, bare_s = [], [], []
    n = 0
    for i in range(args.repeats):
        with tempfile.TemporaryDirectory() as tmp:
            t, run_id = time_sweep(Path(args.protocol), Path(tmp) / "sweep.sqlite")
            p = time_sweep_process(Path(args.protocol), Path(tmp) / "process.sqlite")
            with Store(Path(tmp) / "sweep.sqlite", read_only=True) as store:
                groups = list(rowtable.point_rows(store, run_id))
            n = sum(len(g) for g in groups)
            conn = rowtable.connect(Path(tmp) / "bare.sqlite")
            b = rowtable.timed_insert(conn, groups)
            conn.close()
        sweep_s.append(t)
        process_s.append(p)
        bare_s.append(b)
        print(f"repeat {i + 1}: sweep {t:.2f} s in-process, {p:.2f} s as a process; "
              f"bare executemany {b:.2f} s")
    ts, tp, tb = (statistics.median(x) for x in (sweep_s, process_s, bare_s))
    print(f"samples: {n:,}")
    print(f"sweep on the twin into SQLite, in-process: {n / ts:,.0f} samples/s ({ts:.2f} s wall)")
    print(f"`rigtool sweep --sim` as a process:        {n / tp:,.0f} samples/s ({tp:.2f} s wall)")
    print(f"bare sqlite3 executemany of the rows:      {n / tb:,.0f} samples/s ({tb:.2f} s)")
    print(f"ratio (sweep / bare samples per second): in-process {tb / ts:.2f}, "
          f"as a process {tb / tp:.2f}   goal >= 0.8 both")


if __name__ == "__main__":
    main()
