"""Benchmark: `calibrate_run` vs a bare sqlite3 + numpy read of the same samples.

Builds (or reuses, with --db) a synthetic 401-point x 3000-sample percent sweep written through
the Store (true C_p 1.926e-5 forward), then times, in this process and interleaved:
calibrate_run; a bare read of the columns it needs as rigtool stores them (one SELECT of the
column BLOBs, np.frombuffer); and a bare read of the same samples from the row table of
schema v7 (one SELECT, fetchall, np.array), the baseline the performance issue was set
against. Then it times `rigtool calibrate` as a whole process. Prints the times and ratios
(goal: <= 1.3x in-process, <= 1.5x as a process). --run times an existing run of --db instead.

    python benchmarks/bench_calibrate.py [--db bench.sqlite] [--repeats 5] [--run RUN_ID]
"""

from __future__ import annotations

import argparse
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import rigtool
from rigtool.analysis.calibrate import calibrate_run
from rigtool.store import BLOB_DTYPE, StepRecord, Store

sys.path.insert(0, str(Path(__file__).parent))
import rowtable  # noqa: E402  (the v7 row table: the issue's baseline)

RUN_NAME = "bench-calibrate"
COLUMNS = ("step_id", "t_s", "thrust_n", "speed_rpm", "current_a")


def build_run(store: Store, n_points: int, n_samples: int, seed: int = 1,
              rate: float = 1000.0, lean: bool = False) -> str:
    """A Luo-style sweep: +-100 % command, f = C_p|n|n, I = C_n|n|^3 + I_0, noise and drift,
    sampled at `rate` Hz; `lean`: without the five F/T channels that are all zeros (less disk
    for the largest runs)."""
    rng = np.random.default_rng(seed)
    commands = np.linspace(-100.0, 100.0, n_points)
    protocol = {"command": {"unit": "percent"},
                "metadata": {"propeller_diameter_m": 0.12, "water_density_kg_m3": 1000.0}}
    run_id = store.create_run(name=RUN_NAME, protocol=protocol, protocol_path=None, rig={},
                              plan=[], metadata={"points": n_points, "samples": n_samples},
                              seed=seed, command_unit="percent", tool_version=rigtool.__version__)
    tt = np.arange(n_samples) / rate
    t = 0.0
    previous = 0.0
    store.add_event(run_id, "tare", {"bias": [0.4, 0.0, 0.0, 0.0, 0.0, 0.0]}, t_s=0.0)
    for i, c in enumerate(commands):
        target = 1800.0 * c / 100.0 if abs(c) > 2.0 else 0.0
        n = target + (previous - target) * np.exp(-(tt + 0.5) / 0.2) + rng.normal(0, 2, n_samples)
        previous = target
        cp = np.where(n >= 0, 1.926e-5, 0.8 * 1.926e-5)
        thrust = (cp * np.abs(n) * n + rng.normal(0, 0.25, n_samples)
                  + 0.1 * np.sin(2 * np.pi * 31 * tt) + 0.02 * (t / 3600.0))
        current = 1.2e-9 * np.abs(n) ** 3 + 0.3 + rng.normal(0, 0.05, n_samples)
        zeros = np.zeros(n_samples)
        samples = {"t_s": t + 0.5 + tt, "fx": -thrust, "fy": zeros, "fz": zeros, "tx": zeros,
                   "ty": zeros, "tz": zeros, "thrust_n": thrust, "speed_rpm": n,
                   "current_a": current, "voltage_v": zeros + 48.0, "command": zeros + c}
        if lean:
            for name in ("fy", "fz", "tx", "ty", "tz"):
                del samples[name]
        step = StepRecord(i, float(c), "percent", 1.0, 0, "up", t, t + 0.5,
                          t + 0.5 + n_samples / rate, 0.5, True, rate)
        store.add_step(run_id, step, samples)
        t += 0.5 + n_samples / rate
        if i % 50 == 49:
            store.add_event(run_id, "tare", {"bias": [0.4 - 0.02 * t / 3600, 0, 0, 0, 0, 0]},
                            t_s=t)
    store.finish_run(run_id, "completed")
    return run_id


def find_run(store: Store, n_points: int, n_samples: int) -> str | None:
    for row in store.runs(limit=1000):
        if row["name"] == RUN_NAME and row["n_steps"] == n_points:
            meta = store.run(row["id"])["metadata"]
            if meta.get("samples") == n_samples:
                return row["id"]
    return None


def bare_read(db: Path, run_id: str) -> dict[str, np.ndarray]:
    """The reference: one SELECT of the needed column BLOBs joined to steps, into numpy."""
    conn = sqlite3.connect(str(db))
    try:
        rows = conn.execute(
            f"SELECT b.n, {', '.join('b.' + c for c in COLUMNS[1:])} FROM sample_blocks b "
            "JOIN steps st ON st.id = b.step_id WHERE st.run_id = ? ORDER BY st.idx, b.chunk",
            (run_id,)).fetchall()
        return {c: np.concatenate([np.frombuffer(r[i], BLOB_DTYPE) for r in rows])
                for i, c in enumerate(COLUMNS[1:], start=1)}
    finally:
        conn.close()


def bare_row_read(db: Path, run_id: str) -> np.ndarray:
    """The issue's reference: one SELECT of the sample rows of a v7 row table, into numpy."""
    conn = sqlite3.connect(str(db))
    try:
        cur = conn.execute(
            f"SELECT {', '.join('s.' + c for c in COLUMNS)} FROM samples s "
            "JOIN steps st ON st.id = s.step_id WHERE st.run_id = ? ORDER BY s.rowid", (run_id,))
        return np.array(cur.fetchall(), dtype=float)
    finally:
        conn.close()


def calibrate_process(db: Path, run_id: str, out: Path) -> None:
    subprocess.run([sys.executable, "-m", "rigtool", "calibrate", run_id, "--db", str(db),
                    "--out", str(out)], check=True, capture_output=True)


def timed(fns, repeats: int) -> list[list[float]]:
    """Run the functions in turn, `repeats` rounds (interleaved so load changes hit both)."""
    out: list[list[float]] = [[] for _ in fns]
    for _ in range(repeats):
        for fn, times in zip(fns, out, strict=True):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--db", type=Path, help="database to build the run in, or reuse it from")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--points", type=int, default=401)
    ap.add_argument("--samples", type=int, default=3000)
    ap.add_argument("--run", help="time this existing run of --db instead (e.g. a simulator sweep)")
    args = ap.parse_args(argv)

    with tempfile.TemporaryDirectory() as tmp:
        db = args.db or Path(tmp) / "bench.sqlite"
        store = Store(db)
        run_id = store.resolve_run_id(args.run) if args.run else find_run(
            store, args.points, args.samples)
        if run_id is None:
            t0 = time.perf_counter()
            run_id = build_run(store, args.points, args.samples)
            print(f"built run {run_id} ({args.points} x {args.samples} samples) "
                  f"in {time.perf_counter() - t0:.1f} s")
        else:
            print(f"reusing run {run_id} in {db}")
        n = len(bare_read(db, run_id)["t_s"])
        rows_db = Path(tmp) / "rows.sqlite"
        rowtable.copy_run(store, run_id, rows_db)
        cal = calibrate_run(store, run_id)  # warm-up (imports, page cache)
        t_read, t_rows, t_cal, t_proc = timed([
            lambda: bare_read(db, run_id), lambda: bare_row_read(rows_db, run_id),
            lambda: calibrate_run(store, run_id),
            lambda: calibrate_process(db, run_id, Path(tmp) / "cal")], args.repeats)
        store.close()
    read_s, rows_s = statistics.median(t_read), statistics.median(t_rows)
    cal_s, proc_s = statistics.median(t_cal), statistics.median(t_proc)
    print(f"samples: {n}")
    print(f"bare read of the stored column BLOBs: median {read_s:.3f} s (min {min(t_read):.3f})")
    print(f"bare read of v7 rows (the old layout): median {rows_s:.3f} s (min {min(t_rows):.3f})")
    print(f"calibrate_run, in-process:            median {cal_s:.3f} s (min {min(t_cal):.3f})")
    print(f"`rigtool calibrate` as a process:     median {proc_s:.3f} s (min {min(t_proc):.3f})")
    print(f"ratio to the v7 row read: in-process {cal_s / rows_s:.2f}x (goal <= 1.3x), "
          f"process {proc_s / rows_s:.2f}x (goal <= 1.5x)")
    print(f"ratio to the BLOB read:   in-process {cal_s / read_s:.1f}x, process "
          f"{proc_s / read_s:.1f}x (the read is no longer the cost: analysis is)")
    cp = cal.sections[0].fits.get("C_p_fwd")
    if cp is not None:
        print(f"C_p_fwd = {cp.value:.5g} [{cp.lo:.5g}, {cp.hi:.5g}] N/(r/min)^2")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
