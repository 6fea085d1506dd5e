"""End-to-end sweep throughput on the simulator vs a bare sqlite3 executemany of the same rows.

Runs a protocol on the twin into a fresh database (samples/s, wall time), then inserts the
very same sample rows with plain sqlite3 (same table definition and pragmas, one
transaction per point as the engine commits) and prints the ratio of samples/s.
Both are measured in this process, so machine noise hits both alike.

    python benchmarks/bench_sweep.py                       # full luo2020-baseline (1.2 M samples)
    python benchmarks/bench_sweep.py protocols/quick-demo.yaml --repeats 3
"""

from __future__ import annotations

import argparse
import sqlite3
import statistics
import tempfile
import time
from pathlib import Path

from rigtool.progress import SilentReporter
from rigtool.store import SAMPLE_COLUMNS, Store, create_schema
from rigtool.sweep import resolve, run_sweep

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


def rows_by_step(db: Path, run_id: str) -> list[list[tuple]]:
    conn = sqlite3.connect(db)
    steps = [r[0] for r in conn.execute("SELECT id FROM steps WHERE run_id = ? ORDER BY idx", (run_id,))]
    cols = ", ".join(SAMPLE_COLUMNS)
    out = [conn.execute(f"SELECT {cols} FROM samples WHERE step_id = ?", (s,)).fetchall() for s in steps]
    conn.close()
    return out


def time_bare_insert(groups: list[list[tuple]], db: Path) -> float:
    conn = sqlite3.connect(db, isolation_level=None)
    conn.execute("PRAGMA journal_mode=WAL")
    conn.execute("PRAGMA synchronous=NORMAL")
    create_schema(conn)
    sql = f"INSERT INTO samples ({', '.join(SAMPLE_COLUMNS)}) VALUES ({', '.join('?' * len(SAMPLE_COLUMNS))})"
    t0 = time.perf_counter()
    for rows in groups:
        conn.execute("BEGIN IMMEDIATE")
        conn.executemany(sql, rows)
        conn.execute("COMMIT")
    elapsed = time.perf_counter() - t0
    conn.close()
    return elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("protocol", nargs="?", default=str(ROOT / "protocols/luo2020-baseline.yaml"))
    parser.add_argument("--repeats", type=int, default=1)
    args = parser.parse_args()
    sweep_s, bare_s = [], []
    n = 0
    for i in range(args.repeats):
        with tempfile.TemporaryDirectory() as tmp:
            t, run_id = time_sweep(Path(args.protocol), Path(tmp) / "sweep.sqlite")
            groups = rows_by_step(Path(tmp) / "sweep.sqlite", run_id)
            n = sum(len(g) for g in groups)
            b = time_bare_insert(groups, Path(tmp) / "bare.sqlite")
        sweep_s.append(t)
        bare_s.append(b)
        print(f"repeat {i + 1}: sweep {t:.2f} s, bare executemany {b:.2f} s")
    ts, tb = statistics.median(sweep_s), statistics.median(bare_s)
    print(f"samples: {n:,}")
    print(f"sweep on the twin into SQLite: {n / ts:,.0f} samples/s ({ts:.2f} s wall)")
    print(f"bare sqlite3 executemany:      {n / tb:,.0f} samples/s ({tb:.2f} s)")
    print(f"ratio (sweep / bare samples per second): {tb / ts:.2f}   target >= 0.5, later 0.8")


if __name__ == "__main__":
    main()
