"""`rigtool import` throughput on a ramp log vs a bare sqlite3 executemany of the same rows.

Writes a time-series CSV whose command ramps a little on every row (so every row is its own
point, the worst case for the writer), imports it into a fresh database and prints rows/s.
Then it inserts the very same sample rows with plain sqlite3 (same schema and pragmas, one
transaction) and prints the ratio. Both are measured in this process, so machine noise hits
both alike.

    python benchmarks/bench_import.py                  # 1,000,000 rows
    python benchmarks/bench_import.py --rows 100000 --repeats 3
    python benchmarks/bench_import.py --hold 1000      # a time series: 1000 rows per command
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from rigtool.importers import Mapping, import_file, with_overrides
from rigtool.store import Store

sys.path.insert(0, str(Path(__file__).parent))
import rowtable  # noqa: E402  (the v7 row table: the baseline)


def write_ramp_log(path: Path, rows: int, hold: int = 1, seed: int = 0) -> None:
    """A 1 kHz log: command ramps 1100 -> 1900 us, a new value every `hold` rows."""
    rng = np.random.default_rng(seed)
    t = np.arange(rows) / 1000.0
    cmd = 1100.0 + 800.0 * (np.arange(rows) // hold) * hold / rows
    thrust = np.sign(cmd - 1500) * ((cmd - 1500) / 400) ** 2 * 40 + rng.normal(0, 0.01, rows)
    with path.open("w", encoding="utf-8") as fh:
        fh.write("t,cmd,F\n")
        for chunk in range(0, rows, 100_000):
            sl = slice(chunk, chunk + 100_000)
            fh.write("\n".join(f"{a:.3f},{b:.6f},{c:.5f}" for a, b, c in
                               zip(t[sl], cmd[sl], thrust[sl], strict=True)) + "\n")


def time_import(csv_path: Path, db: Path) -> tuple[float, str]:
    mapping = with_overrides(Mapping(), cols=["time=t", "command=cmd", "thrust=F"],
                             command_unit="pulse_us")
    store = Store(db)
    t0 = time.perf_counter()
    result = import_file(store, csv_path, mapping)
    elapsed = time.perf_counter() - t0
    store.close()
    assert result.n_skipped == 0, result.summary()
    return elapsed, str(result.run_id)


def stored_rows(db: Path, run_id: str) -> list[tuple]:
    with Store(db, read_only=True) as store:
        return [row for rows in rowtable.point_rows(store, run_id) for row in rows]


def time_bare_insert(rows: list[tuple], db: Path) -> float:
    """The baseline: the same rows into the v7 row table, in one transaction."""
    conn = rowtable.connect(db)
    elapsed = rowtable.timed_insert(conn, [rows])
    conn.close()
    return elapsed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=1_000_000)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--hold", type=int, default=1, help="rows per command (1: every row a point)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        log = folder / "ramp.csv"
        write_ramp_log(log, args.rows, args.hold)
        ours, bare = [], []
        for i in range(args.repeats):
            db = folder / f"import{i}.sqlite"
            elapsed, run_id = time_import(log, db)
            ours.append(elapsed)
            rows = stored_rows(db, run_id)
            assert len(rows) == args.rows, len(rows)
            bare.append(time_bare_insert(rows, folder / f"bare{i}.sqlite"))
        t_ours, t_bare = statistics.median(ours), statistics.median(bare)
        print(f"rows: {args.rows:,} ({args.hold} row(s) per command), repeats: {args.repeats}")
        print(f"rigtool import:           {t_ours:8.2f} s  {args.rows / t_ours:12,.0f} rows/s")
        print(f"bare sqlite3 executemany: {t_bare:8.2f} s  {args.rows / t_bare:12,.0f} rows/s")
        print(f"ratio (import / bare rows/s): {t_bare / t_ours:.3f}")


if __name__ == "__main__":
    main()
