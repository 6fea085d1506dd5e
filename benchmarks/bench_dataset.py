"""`rigtool export --all DIR`: wall time and peak memory of a first export of one run of 0.1, 1.2
(and, with --big, 12) million samples (the synthetic 400-point sweep of bench_calibrate.py),
then of an export that finds nothing changed, each a process of its own. Memory should not
grow with the run: the samples go through in chunks of Store.iter_samples.

    python benchmarks/bench_dataset.py [--big]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from bench_calibrate import build_run  # noqa: E402

from rigtool.store import Store  # noqa: E402

POINTS = 400
RUNNER = ("import resource, sys; from rigtool.cli import main; rc = main(sys.argv[1:]); "
          "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr); "
          "sys.exit(rc)")


def _export(db: Path, out: Path) -> tuple[float, float]:
    """(wall seconds, peak RSS in MB) of `rigtool export --all` in its own process."""
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", RUNNER, "export", "--all", "--out", str(out), "--db",
                           str(db)], capture_output=True, text=True, check=True)
    return time.perf_counter() - t0, int(proc.stderr.strip().splitlines()[-1]) / 1024.0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--big", action="store_true", help="also 12 M samples (~2 GB disk)")
    sizes = [100_000, 1_200_000] + ([12_000_000] if parser.parse_args().big else [])
    with tempfile.TemporaryDirectory() as tmp:
        for n in sizes:
            db = Path(tmp) / f"run{n}.sqlite"
            with Store(db) as store:
                build_run(store, POINTS, n // POINTS)
            out = Path(tmp) / f"ds{n}"
            (t1, m1), (t2, m2) = _export(db, out), _export(db, out)
            size = sum(p.stat().st_size for p in out.rglob("*.parquet")) / 2**20
            print(f"{n / 1e6:5.1f} M samples: first export {t1:6.2f} s {m1:5.0f} MB peak, "
                  f"{size:6.1f} MB of Parquet; unchanged export {t2:5.2f} s {m2:5.0f} MB peak",
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
