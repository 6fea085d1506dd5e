"""Cost as runs grow: sweep, calibrate, report and Parquet export of runs of 0.1, 1.2 (and,
with --big, 12) million samples, each command a process, with its wall time and peak memory.

The sweep is `rigtool sweep --sim` of a 400-point protocol on the twin (more samples per
point as the run grows). The other commands work on the synthetic Luo-style sweep of
bench_calibrate.py (400 points), written through the Store. For each size the script prints time
and peak RSS per command, and between sizes the marginal cost: seconds and bytes per added
sample. Linear cost shows as a constant marginal time per sample; bounded memory as a
constant (stated) number of bytes per sample.

    python benchmarks/bench_scaling.py [--big]
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
COMMANDS = {
    "sweep": ["sweep", "{tmp}/scaling-{n}.yaml", "--sim"],
    "calibrate": ["calibrate", "last", "--out", "{tmp}/cal"],
    "report": ["report", "last", "--out", "{tmp}/cal"],
    "export": ["export", "last", "--format", "parquet", "--out", "{tmp}/exp"],
}


def _run(args: list[str], db: Path) -> tuple[float, float]:
    """(wall seconds, peak RSS in MB) of one rigtool command in its own process."""
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", RUNNER, *args, "--db", str(db)],
                         capture_output=True, text=True, check=True)
    wall = time.perf_counter() - t0
    return wall, int(out.stderr.strip().splitlines()[-1]) / 1024.0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--big", action="store_true", help="also 12 M samples (minutes, ~2 GB disk)")
    args = parser.parse_args()
    sizes = [100_000, 1_200_000] + ([12_000_000] if args.big else [])
    results: dict[int, dict[str, tuple[float, float]]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for n in sizes:
            db = Path(tmp) / f"run{n}.sqlite"
            with Store(db) as store:
                build_run(store, POINTS, n // POINTS)
            Path(tmp, f"scaling-{n}.yaml").write_text(SWEEP_PROTOCOL.format(n=n, per_point=n // POINTS))
            results[n] = {name: _run([a.format(tmp=tmp, n=n) for a in cmd],
                                     Path(tmp) / f"sweep{n}.sqlite" if name == "sweep" else db)
                          for name, cmd in COMMANDS.items()}
            row = "  ".join(f"{k} {t:6.2f} s {m:6.0f} MB" for k, (t, m) in results[n].items())
            print(f"{n / 1e6:5.1f} M samples: {row}", flush=True)
    for a, b in zip(sizes, sizes[1:], strict=False):
        added = b - a
        parts = []
        for name in COMMANDS:
            (ta, ma), (tb, mb) = results[a][name], results[b][name]
            parts.append(f"{name} {1e6 * (tb - ta) / added:5.2f} s/M samples, "
                         f"{(mb - ma) * 2**20 / added:5.0f} B/sample")
        print(f"{a / 1e6:g} -> {b / 1e6:g} M, marginal: " + "; ".join(parts))
    return 0


if __name__ == "__main__":
    sys.exit(main())
