"""Issue 48 figures: free-running identification through the CLI against the vehicle twin's
published truth, on seeds given on the command line (held-out seeds: 48000 and up).

Per case (truth set, noise): each parameter's error (typical = median over seeds, and the
worst), how often its 95 % interval covers the truth, the worst held-out prediction error (%
of range), and with --method all how far the global optimum lies from least squares'.

    python benchmarks/bench_vehicle.py 48000 48005 [--method all] [--duration 600]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rigtool.analysis.vehicle.model import NAMES  # noqa: E402
from rigtool.sim.vehicle_params import BLUEROV2, BLUEROV2_HEAVY  # noqa: E402

PROTOCOL = Path(__file__).resolve().parents[1] / "protocols" / "esc-1100-1900.yaml"
TRUTHS = {"bluerov2": BLUEROV2, "bluerov2-heavy": BLUEROV2_HEAVY}
CASES = (("bluerov2", 0.01), ("bluerov2", 0.03), ("bluerov2", 0.07), ("bluerov2-heavy", 0.03))
GROUPS = {"added mass": slice(0, 6), "linear damping": slice(6, 12),
          "quadratic damping": slice(12, 18)}


def calibration(tmp: Path) -> Path:
    """The twin ESC thruster swept and calibrated through the CLI."""
    db = tmp / "t.sqlite"
    subprocess.run(["rigtool", "sweep", str(PROTOCOL), "--sim", "--db", str(db)], check=True,
                   capture_output=True)
    subprocess.run(["rigtool", "calibrate", "last", "--db", str(db), "--out", str(tmp / "cal")],
                   check=True, capture_output=True)
    (folder,) = (tmp / "cal").iterdir()
    return folder


def run_one(cal: Path, truth: str, noise: float, seed: int, args: argparse.Namespace,
            tmp: Path) -> dict | str:
    """Fly, identify and read back one case; a refusal's message instead of a result."""
    flight, out = tmp / f"f{seed}", tmp / f"m{seed}"
    subprocess.run(["rigtool", "sim-vehicle", "--calibration", str(cal), "--out", str(flight),
                    "--truth", truth, "--seed", str(seed), "--noise", str(noise),
                    "--duration", str(args.duration)], check=True, capture_output=True)
    done = subprocess.run(["rigtool", "identify", str(flight / "vehicle.yaml"),
                           str(flight / "log.csv"), "--out", str(out), "--method", args.method,
                           "--seed", str(seed)], capture_output=True, text=True)
    if done.returncode:
        return f"seed {seed}: exit {done.returncode}: {done.stderr.strip()[:300]}"
    return json.loads((out / "identification.json").read_text())


def summarise(truth: np.ndarray, docs: list[dict], names: list[str]) -> list[str]:
    """Lines of the table for one case."""
    err, cover = [], []
    for doc in docs:
        p = [doc["parameters"][n] for n in names]
        value = np.array([np.nan if x["value"] is None else x["value"] for x in p])
        err.append(np.abs(value - truth) / np.where(truth == 0, np.nan, np.abs(truth)))
        cover.append([x["ci95"] is not None and x["ci95"][0] <= t <= x["ci95"][1]
                      for x, t in zip(p, truth, strict=True)])
    err, cover = np.array(err) * 100, np.array(cover)
    lines = []
    for group, cut in GROUPS.items():
        e = err[:, cut]
        lines.append(f"  {group:17s} error median {np.nanmedian(e):5.1f} %  worst "
                     f"{np.nanmax(e):6.1f} % ({names[cut][int(np.nanargmax(e) % 6)]}); "
                     f"covered {int(cover[:, cut].sum())}/{cover[:, cut].size}")
    worst = max(h["percent_of_range"] for d in docs for h in d["held_out"])
    lines.append(f"  held-out prediction worst {worst:.2f} % of range")
    agree = [d["global_vs_least_squares"]["largest_relative_difference"] for d in docs
             if d["global_vs_least_squares"] is not None]
    if agree:
        lines.append(f"  global vs least squares: worst {100 * max(agree):.2f} %")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("first", type=int)
    parser.add_argument("last", type=int)
    parser.add_argument("--method", default="nls")
    parser.add_argument("--duration", type=float, default=600.0)
    parser.add_argument("--case", action="append", metavar="TRUTH:NOISE",
                        help="e.g. bluerov2:0.03 (repeatable; default: all four cases)")
    args = parser.parse_args()
    names = list(NAMES)  # the truth's order (identification.json sorts its keys)
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        cal = calibration(tmp)
        cases = [(c.split(":")[0], float(c.split(":")[1])) for c in args.case] if args.case \
            else CASES
        for truth_name, noise in cases:
            p = TRUTHS[truth_name]
            truth = np.array(p.added_mass + p.linear_damping + p.quadratic_damping)
            results = [run_one(cal, truth_name, noise, s, args, tmp)
                       for s in range(args.first, args.last)]
            docs = [r for r in results if isinstance(r, dict)]
            for refused in (r for r in results if isinstance(r, str)):
                print(f"  refused: {refused}")
            if not docs:
                continue
            print(f"{truth_name}, noise {100 * noise:g} %, {len(docs)} seeds, "
                  f"{args.duration:g} s logs, method {args.method}")
            print("\n".join(summarise(truth, docs, names)), flush=True)


if __name__ == "__main__":
    main()
