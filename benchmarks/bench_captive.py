"""Benchmark: captive runs recover the vehicle twin's damping, with honest intervals?

Cells: each truth (BlueROV2 from Wu 2018, BlueROV2 Heavy from von Benzon 2022) held at yaw
and at angle-of-attack settings, at a flow unsteadiness (`--noise`, fractions of the force,
default 0.01, 0.03 and 0.07: the 1-7 % the identification papers test against). Each cell
runs protocols/captive-tow.yaml (its angle kind and vehicle swapped in) on `--seeds` held-out
seeds and fits it as `rigtool calibrate` does (analysis.captive.fit_captive).

Per coefficient it prints the coverage of the 95 % interval, the typical (median) and worst
relative error (a zero truth, the Heavy's Y_v, is judged against its quadratic term's size
times 1 m/s), and the mean half-width over the scatter of the estimates (about 1.96 when the
intervals are honest and no wider than they need be). Drag and lift per angle are summarised
the same way, pooled over angles.

    python benchmarks/bench_captive.py [--seeds 40] [--first-seed 52000] [--noise 0.01,0.03,0.07]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from rigtool.analysis.captive import fit_captive, truth_lift_drag  # noqa: E402
from rigtool.analysis.dataset import load_captive  # noqa: E402
from rigtool.cli import main  # noqa: E402
from rigtool.sim.flow import VEHICLES  # noqa: E402
from rigtool.store import Store  # noqa: E402

PROTOCOL = ROOT / "protocols" / "captive-tow.yaml"


def run_cell(vehicle: str, angle: str, noise: float, seeds: list[int], tmp: Path) -> dict:
    """Estimates per coefficient name: list of (value, lo, hi, truth, scale)."""
    doc = yaml.safe_load(PROTOCOL.read_text())
    doc.pop("rig")
    doc["simulator"].update(vehicle=vehicle, flow_noise_frac=noise)
    doc["captive"]["angle"] = angle
    path = tmp / f"{vehicle}-{angle}-{noise}.yaml"
    path.write_text(yaml.safe_dump(doc))
    truth = VEHICLES[vehicle]
    across = 1 if angle == "yaw" else 2
    out: dict[str, list] = {}
    for seed in seeds:
        db = tmp / f"{path.stem}-{seed}.sqlite"
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            assert main(["sweep", str(path), "--sim", "--seed", str(seed), "--db", str(db)]) == 0
        with Store(db) as store:
            result = fit_captive(load_captive(store, store.resolve_run_id("last")))
        db.unlink()
        for k in (0, across):
            law = result.laws[k]
            scale = abs(truth.quadratic_damping[k])
            for c, want in ((law.linear, truth.linear_damping[k]),
                            (law.quadratic, truth.quadratic_damping[k])):
                out.setdefault(c.name, []).append((c.value, c.lo, c.hi, want, abs(want) or scale))
        for ld in result.lift_drag:
            want = truth_lift_drag(truth.linear_damping, truth.quadratic_damping, ld.angle_deg,
                                   angle)
            size = abs(want[1]) + abs(want[3])  # a zero truth: against the force's size
            for c, w in zip((ld.drag_linear, ld.drag_quadratic, ld.lift_linear,
                             ld.lift_quadratic), want, strict=True):
                name = f"{c.name} (all angles)"
                out.setdefault(name, []).append((c.value, c.lo, c.hi, w,
                                                 abs(w) if abs(w) > 1e-9 * size else size))
    return out


def summary(rows: list) -> tuple[float, float, float, float, int]:
    """(coverage, median |rel err|, worst |rel err|, half-width / scatter, n)."""
    a = np.array(rows, dtype=float)
    value, lo, hi, want, scale = a.T
    err = np.abs(value - want) / scale
    covered = (lo <= want) & (want <= hi)
    spread = np.std(value - want, ddof=1) if len(value) > 1 else np.nan
    ratio = float(np.mean((hi - lo) / 2) / spread) if spread > 0 else np.nan
    return float(covered.mean()), float(np.median(err)), float(err.max()), ratio, len(value)


def main_bench() -> None:
    """Run every cell and print one table."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=40)
    ap.add_argument("--first-seed", type=int, default=52000)
    ap.add_argument("--noise", default="0.01,0.03,0.07")
    args = ap.parse_args()
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    print(f"seeds {seeds[0]}..{seeds[-1]} (held out); {PROTOCOL.name}")
    print(f"{'cell':34s} {'coefficient':22s} {'cover':>6s} {'median':>8s} {'worst':>8s} "
          f"{'hw/sd':>6s}")
    with tempfile.TemporaryDirectory() as tmp:
        for noise in (float(x) for x in args.noise.split(",")):
            for vehicle in VEHICLES:
                for angle in ("yaw", "attack"):
                    cell = run_cell(vehicle, angle, noise, seeds, Path(tmp))
                    for name, rows in cell.items():
                        cov, med, worst, ratio, n = summary(rows)
                        print(f"{vehicle + ' ' + angle + f' noise {noise:g}':34s} {name:22s} "
                              f"{cov:6.1%} {med:8.2%} {worst:8.2%} {ratio:6.2f}", flush=True)


if __name__ == "__main__":
    main_bench()
