"""CPU of each shipped protocol's simulated sweep, this checkout against a baseline commit.

Times `run_sweep` of every protocols/*.yaml on the twin (`--sim`) in-process with
time.process_time(), once for this checkout and once for the baseline (default: the merge-base
with main, exported by `git archive` to a temporary folder), each in its own interpreter with
that tree first on PYTHONPATH, alternating so machine noise hits both alike; prints the ratios.

    python benchmarks/bench_sweep_cpu.py                   # every shipped protocol, 1 repeat
    python benchmarks/bench_sweep_cpu.py --base main --repeats 3 protocols/luo2020-baseline.yaml
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

_CHILD = """
import sys, tempfile, time
from pathlib import Path
from rigtool.progress import SilentReporter
from rigtool.store import Store
from rigtool.sweep import resolve, run_sweep
with tempfile.TemporaryDirectory() as d:
    setup = resolve(Path(sys.argv[1]), sim=True)
    store = Store(Path(d) / "run.db")
    t0 = time.process_time()
    outcome = run_sweep(setup, store, SilentReporter())
    cpu_s = time.process_time() - t0
    store.close()
print(cpu_s, outcome.status)
"""


def export_tree(rev: str, dest: Path) -> None:
    """Write the files of commit `rev` into `dest` (git archive, no work tree of its own)."""
    archive = dest / "tree.tar"
    subprocess.run(["git", "-C", str(ROOT), "archive", "-o", str(archive), rev], check=True)
    with tarfile.open(archive) as tar:
        tar.extractall(dest / "tree", filter="data")


def sweep_cpu_s(tree: Path, protocol: Path) -> float:
    """CPU seconds of one simulated sweep of `protocol` with rigtool imported from `tree`."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    done = subprocess.run([sys.executable, "-c", _CHILD, str(protocol)], env=env, check=True,
                          capture_output=True, text=True, cwd=tree)
    cpu_s, status = done.stdout.split()
    if status != "completed":
        raise SystemExit(f"{protocol.name}: sweep {status} under {tree}")
    return float(cpu_s)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("protocols", nargs="*", type=Path)
    parser.add_argument("--base", default=None, help="baseline commit (default: merge-base with main)")
    parser.add_argument("--repeats", type=int, default=1, help="sweeps per side; the minimum counts")
    args = parser.parse_args()
    base = args.base or subprocess.run(["git", "-C", str(ROOT), "merge-base", "HEAD", "main"],
                                       check=True, capture_output=True, text=True).stdout.strip()
    protocols = [p.resolve() for p in args.protocols] or sorted((ROOT / "protocols").glob("*.yaml"))
    with tempfile.TemporaryDirectory() as tmp:
        export_tree(base, Path(tmp))
        base_tree = Path(tmp) / "tree"
        print(f"baseline {base[:10]}; CPU s per sweep, minimum of {args.repeats}")
        print(f"{'protocol':28s} {'base':>8s} {'this':>8s} {'ratio':>6s}")
        ratios = []
        for protocol in protocols:
            base_s, this_s = [], []
            for _ in range(args.repeats):
                base_s.append(sweep_cpu_s(base_tree, protocol))
                this_s.append(sweep_cpu_s(ROOT, protocol))
            ratio = min(this_s) / min(base_s)
            ratios.append(ratio)
            print(f"{protocol.name:28s} {min(base_s):8.2f} {min(this_s):8.2f} {ratio:6.2f}", flush=True)
        ratios.sort()
        print(f"ratio: worst {ratios[-1]:.2f}, median {ratios[len(ratios) // 2]:.2f}")


if __name__ == "__main__":
    main()
