"""Parquet export of a run's samples: rigtool's numpy-built export against the old way
(rows of the schema-v7 row table fetched as tuples, columns rebuilt in Python, `pa.array`
per column), both measured in this process on the same samples, interleaved.

Builds (or reuses, with --db) a run of 400 points x 3000 samples (1.2 M samples) through the
Store, then times `export_run(..., "parquet")` and the baseline, and prints their times,
file sizes and the speed-up (goal: >= 5x).

    python benchmarks/bench_export.py [--db bench.sqlite] [--repeats 3]
"""

from __future__ import annotations

import argparse
import sqlite3
import statistics
import sys
import tempfile
import time
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from rigtool.export import export_run
from rigtool.store import SAMPLE_COLUMNS, Store

sys.path.insert(0, str(Path(__file__).parent))
import rowtable  # noqa: E402  (the v7 row table: the baseline)
from bench_calibrate import build_run  # noqa: E402  (the same synthetic run)

GOAL = 5.0


def tuples_baseline(conn: sqlite3.Connection, run_id: str, path: Path) -> None:
    """What export did before: tuples from the cursor, zip(*rows), pa.array per column."""
    cols = ("step_idx", *SAMPLE_COLUMNS[1:])
    ints = {"step_idx", "seq"}
    schema = pa.schema([(c, pa.int64() if c in ints else pa.float64()) for c in cols])
    cur = conn.execute(
        f"SELECT st.idx, {', '.join('s.' + c for c in SAMPLE_COLUMNS[1:])} FROM samples s "
        "JOIN steps st ON st.id = s.step_id WHERE st.run_id = ? ORDER BY s.rowid", (run_id,))
    with pq.ParquetWriter(str(path), schema) as writer:
        while rows := cur.fetchmany(50_000):
            columns = list(zip(*rows, strict=True))
            writer.write_table(pa.Table.from_arrays(
                [pa.array(c, type=f.type) for c, f in zip(columns, schema, strict=True)],
                schema=schema))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--db", type=Path)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        db = args.db or Path(tmp) / "bench.sqlite"
        store = Store(db)
        runs = store.run_ids()
        run_id = runs[-1] if runs else build_run(store, 400, 3000)
        n = len(store.sample_arrays(run_id, ["t_s"])["t_s"])
        rowtable.copy_run(store, run_id, Path(tmp) / "rows.sqlite")
        rows = sqlite3.connect(Path(tmp) / "rows.sqlite")
        ours, base = [], []
        for i in range(args.repeats):
            t0 = time.perf_counter()
            paths = export_run(store, run_id, Path(tmp) / f"ours{i}", "parquet")
            ours.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            tuples_baseline(rows, run_id, Path(tmp) / f"base{i}.parquet")
            base.append(time.perf_counter() - t0)
        samples = next(p for p in paths if p.name.endswith("-samples.parquet"))
        o, b = statistics.median(ours), statistics.median(base)
        print(f"{n:,} samples; export (points, samples, events) {o:.2f} s, "
              f"{samples.stat().st_size / 1e6:.1f} MB samples file; tuples baseline (samples "
              f"only) {b:.2f} s, {(Path(tmp) / 'base0.parquet').stat().st_size / 1e6:.1f} MB")
        print(f"speed-up {b / o:.2f}x (goal >= {GOAL:g}x): {'met' if b / o >= GOAL else 'NOT met'}")
        store.close()
        rows.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
