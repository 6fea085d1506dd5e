"""Equivalence: `rigtool calibrate` of this tree against a reference tree (the whole-run
calibrate before the per-point pass) on held-out twin runs, field by field.

Sweeps shipped protocols on the twin with held-out seeds (61001...), one database per run
(a luo2020-cavitation run after its deep base run, so the quasi-cavitation stage runs; one
run stopped by SIGINT and resumed), then calibrates each run in a process of each tree, on
copies of the same database, and compares every file calibrate writes: calibration.json
value by value, and every CSV table cell by cell (numbers by relative difference, text
exactly). Prints, per run, the fields compared, the largest relative difference and every
field that differs by more than --tol.

    python benchmarks/bench_perpoint_equivalence.py --reference /path/to/old/tree [--seeds 12]
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import signal
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent.parent
PROTOCOLS = HERE / "protocols"
CYCLE = ("quick-demo", "stm32-pwm", "dynamics-steps", "esc-1100-1900", "voltage-sweep",
         "luo2020-baseline", "luo2020-cavitation", "dynamics-steps-esc")
BASE_OF = {"luo2020-cavitation": "luo2020-baseline"}
RESUMED = "quick-demo"  # the protocol of the run stopped and resumed
STOP_AFTER = 5  # points stored before it is stopped
IGNORED = {"created_utc", "tool_version", "run_id", "out_dir", "calibrated_utc"}


def rigtool(tree: Path, *args: str, check: bool = True) -> subprocess.CompletedProcess:
    """A rigtool command in its own process with `tree` first on the path."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    return subprocess.run([sys.executable, "-m", "rigtool", *args], env=env,
                          capture_output=True, text=True, check=check)


def sweep(tree: Path, db: Path, name: str, seed: int, resume: bool = False) -> None:
    """Sweep `name` on the twin into `db` (its base run first), stopped and resumed if asked."""
    for protocol in filter(None, (BASE_OF.get(name), name)):
        args = ["sweep", str(PROTOCOLS / f"{protocol}.yaml"), "--sim", "--seed", str(seed),
                "--db", str(db)]
        if not resume:
            rigtool(tree, *args)
            continue
        env = {**os.environ, "PYTHONPATH": str(tree)}
        proc = subprocess.Popen([sys.executable, "-m", "rigtool", *args], env=env,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        _wait_for_points(db, STOP_AFTER)
        proc.send_signal(signal.SIGINT)
        proc.wait()
        rigtool(tree, "sweep", "--resume", "last", "--db", str(db))
        with sqlite3.connect(db) as conn:
            resumed = conn.execute("SELECT count(*) FROM events WHERE kind = 'resumed'"
                                   ).fetchone()[0]
        if not resumed:
            raise SystemExit(f"{name} seed {seed}: the sweep ended before it was interrupted")


def _wait_for_points(db: Path, n: int, timeout_s: float = 600.0) -> None:
    """Wait until the sweep writing `db` has stored `n` points."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        try:
            with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as conn:
                if conn.execute("SELECT count(*) FROM steps").fetchone()[0] >= n:
                    return
        except sqlite3.Error:
            pass
        time.sleep(0.2)
    raise SystemExit(f"no {n} points in {db} after {timeout_s:g} s")


def calibrate(tree: Path, db: Path, out: Path) -> tuple[Path, str]:
    """Calibrate the last run of `db` with `tree`: its folder and the warnings printed."""
    done = rigtool(tree, "calibrate", "last", "--db", str(db), "--out", str(out))
    return next(out.iterdir()), done.stderr


def number(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


class Diff:
    """Fields compared, the largest relative difference, and the fields beyond `tol`."""

    def __init__(self, tol: float) -> None:
        self.tol, self.fields, self.worst, self.differing = tol, 0, 0.0, []

    def value(self, where: str, a: object, b: object) -> None:
        self.fields += 1
        if isinstance(a, str) and isinstance(b, str):
            x, y = number(a), number(b)
            if x is None or y is None:
                if a != b:
                    self.differing.append(f"{where}: {a!r} != {b!r}")
                return
            a, b = x, y
        if isinstance(a, bool) or isinstance(b, bool) or not (
                isinstance(a, int | float) and isinstance(b, int | float)):
            if a != b:
                self.differing.append(f"{where}: {a!r} != {b!r}")
            return
        if math.isnan(a) and math.isnan(b) or a == b:
            return
        rel = abs(a - b) / max(abs(a), abs(b), 1e-300)
        self.worst = max(self.worst, rel)
        if not rel <= self.tol:
            self.differing.append(f"{where}: {a!r} != {b!r} (rel {rel:.2e})")

    def tree(self, where: str, a: object, b: object) -> None:
        if isinstance(a, dict) and isinstance(b, dict):
            for k in sorted(set(a) | set(b)):
                if k not in IGNORED:
                    self.tree(f"{where}.{k}", a.get(k, "<missing>"), b.get(k, "<missing>"))
        elif isinstance(a, list) and isinstance(b, list):
            if len(a) != len(b):
                self.differing.append(f"{where}: {len(a)} != {len(b)} items")
            for i, (x, y) in enumerate(zip(a, b, strict=False)):
                self.tree(f"{where}[{i}]", x, y)
        else:
            self.value(where, a, b)


def compare(ref: Path, new: Path, diff: Diff) -> None:
    """Every file of two calibration folders: JSON by value, CSV by cell, text exactly."""
    names = sorted({p.name for p in ref.iterdir()} | {p.name for p in new.iterdir()})
    for name in names:
        a, b = ref / name, new / name
        if not (a.is_file() and b.is_file()):
            diff.differing.append(f"{name}: only in {'reference' if a.is_file() else 'new'}")
            continue
        if name.endswith(".json"):
            diff.tree(name, json.loads(a.read_text()), json.loads(b.read_text()))
        elif name.endswith(".csv"):
            ra, rb = (list(csv.reader(p.open())) for p in (a, b))
            if len(ra) != len(rb):
                diff.differing.append(f"{name}: {len(ra)} != {len(rb)} rows")
            for i, (x, y) in enumerate(zip(ra, rb, strict=False)):
                for j, (u, v) in enumerate(zip(x, y, strict=False)):
                    if not (u.strip().startswith("created") and v.strip().startswith("created")):
                        diff.value(f"{name}[{i}][{j}]", u, v)
        elif a.suffix in (".txt", ".md", ".yaml", ".yml", ".h", ".c"):
            diff.value(name, a.read_text(), b.read_text())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reference", type=Path, required=True,
                        help="source tree of the reference rigtool (e.g. a worktree of main)")
    parser.add_argument("--seeds", type=int, default=12)
    parser.add_argument("--first-seed", type=int, default=61001)
    parser.add_argument("--only", type=int, help="only the run of this seed")
    parser.add_argument("--tol", type=float, default=1e-9, help="relative difference reported")
    args = parser.parse_args()
    total_worst, failed = 0.0, 0
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.seeds):
            seed = args.first_seed + k
            name = CYCLE[k % len(CYCLE)]
            resume = k == len(CYCLE)  # the ninth run: stopped and resumed
            name = RESUMED if resume else name
            if args.only is not None and seed != args.only:
                continue
            work = Path(tmp) / str(seed)
            work.mkdir()
            db = work / "run.sqlite"
            t0 = time.perf_counter()
            sweep(HERE, db, name, seed, resume)
            with sqlite3.connect(db) as src, sqlite3.connect(work / "ref.sqlite") as dst:
                src.backup(dst)  # a consistent copy, write-ahead log included
            ref, ref_err = calibrate(args.reference, work / "ref.sqlite", work / "ref")
            new, new_err = calibrate(HERE, db, work / "new")
            diff = Diff(args.tol)
            compare(ref, new, diff)
            diff.value("printed warnings", ref_err.replace(str(work / "ref"), "OUT"),
                       new_err.replace(str(work / "new"), "OUT").replace(str(db), "DB")
                       .replace("DB", str(work / "ref.sqlite")))
            total_worst = max(total_worst, diff.worst)
            failed += bool(diff.differing)
            label = f"{name}{' (resumed)' if resume else ''}"
            print(f"seed {seed} {label:32s} {diff.fields:6d} fields, largest rel diff "
                  f"{diff.worst:.1e}, {len(diff.differing)} beyond {args.tol:g} "
                  f"({time.perf_counter() - t0:.0f} s)", flush=True)
            for line in diff.differing[:20]:
                print("   ", line)
    print(f"{args.seeds} runs: largest relative difference {total_worst:.1e}; "
          f"{failed} run(s) with a field beyond {args.tol:g}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
