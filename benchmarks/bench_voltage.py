"""Benchmark: C_n(U), C_p across voltages and N/W on held-out seeds and twin variants.

Runs the shipped protocols/voltage-sweep.yaml (5 voltages x 1100-1900 us on the ESC twin)
through `rigtool sweep` and `rigtool calibrate` for each twin variant and seed, and compares
with the truth the twin was built with: C_n(U) = cn U0 / U at each voltage (error and whether
the 95 % interval holds it), C_p_fwd, the law's exponent b (-1), whether the C_p values agree
across voltages, and thrust per watt at the 50 % command. Prints the typical (median) and
the worst case. Seeds default to a range not used while developing (dev seeds: 1600, 911-913).

    python benchmarks/bench_voltage.py [--seeds 6] [--first-seed 9400]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import tempfile
from pathlib import Path

import numpy as np

from rigtool.cli import main
from rigtool.sim.physics import ThrusterTwin
from rigtool.thruster_profiles import profile_with_overrides

ROOT = Path(__file__).resolve().parent.parent
VARIANTS = {
    "default": {},
    "hungry-sagging": {"cn": 5.8e-10, "supply_resistance_ohm": 0.08, "cp_forward": 3.0e-6},
    "noisy-deadband": {"current_noise_a": 1.0, "speed_noise_rpm": 45.0, "deadband": 40.0,
                       "voltage_noise_v": 0.2},
}
HALF_COMMAND = 1700.0  # 50 % forward of 1500..1900 us


def one_run(root: Path, variant: dict, seed: int) -> dict:
    text = (ROOT / "protocols" / "voltage-sweep.yaml").read_text()
    extra = "".join(f"\n    {k}: {v}" for k, v in variant.items())
    text = text.replace("seed: 1600", f"seed: {seed}").replace(
        "feedback: [speed_rpm, current_a, voltage_v]",
        "feedback: [speed_rpm, current_a, voltage_v]" + extra)
    folder = Path(tempfile.mkdtemp(dir=root))
    path = folder / f"p{seed}.yaml"
    path.write_text(text)
    db, out = str(folder / f"{seed}.sqlite"), folder / f"cal{seed}"
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(["sweep", str(path), "--sim", "--db", db]) == 0
        assert main(["calibrate", "last", "--db", db, "--out", str(out)]) == 0
    cal_dir = next(out.iterdir())
    doc = json.loads((cal_dir / "calibration.json").read_text())
    rows = _points(cal_dir / "points.csv")
    return {"law": doc["voltage_laws"][0], "points": rows}


def _points(path: Path) -> list[dict]:
    import csv

    with open(path) as fh:
        return list(csv.DictReader(line for line in fh if not line.startswith("#")))


def evaluate(result: dict, variant: dict) -> dict:
    profile = profile_with_overrides("esc-1100-1900", variant)
    law = result["law"]
    cn_err, cn_in, cp_err = [], [], []
    for v in law["voltages"]:
        truth = profile.cn * profile.supply_voltage_v / v["supply_voltage_v"]
        cn = v["C_n"]
        cn_err.append(abs(cn["value"] / truth - 1))
        cn_in.append(cn["lo"] <= truth <= cn["hi"])
        cp_err.append(abs(v["C_p_fwd"]["value"] / profile.cp_forward - 1))
    eff_err, eff_in = [], []
    for row in result["points"]:
        if float(row["command"]) != HALF_COMMAND:
            continue
        twin = ThrusterTwin(profile, seed=0)
        volts = float(row["voltage_set_v"])
        twin.set_supply_voltage(0.0, volts)
        _, f, i = twin.steady_state(HALF_COMMAND)
        truth = f / ((volts - profile.supply_resistance_ohm * i) * i)
        eff = float(row["efficiency_n_per_w"])
        eff_err.append(abs(eff / truth - 1))
        eff_in.append(abs(eff - truth) <= 1.96 * float(row["efficiency_se_n_per_w"]))
    b = law["b"]
    return {"cn_err": max(cn_err), "cn_cover": float(np.mean(cn_in)), "cp_err": max(cp_err),
            "cp_consistent": law["cp_consistent"], "b_covers": b["lo"] <= -1 <= b["hi"],
            "eff_err": max(eff_err), "eff_cover": float(np.mean(eff_in))}


def main_() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=6)
    parser.add_argument("--first-seed", type=int, default=9400)
    args = parser.parse_args()
    print(f"{'variant':16} {'C_n err med/worst':>18} {'C_n cover':>9} {'C_p err worst':>13} "
          f"{'C_p consistent':>14} {'b covers -1':>11} {'N/W err med/worst':>18} "
          f"{'N/W truth in 95%':>16}")
    with tempfile.TemporaryDirectory() as tmp:
        for name, variant in VARIANTS.items():
            res = [evaluate(one_run(Path(tmp), variant, s), variant)
                   for s in range(args.first_seed, args.first_seed + args.seeds)]
            cn = [r["cn_err"] for r in res]
            eff = [r["eff_err"] for r in res]
            print(f"{name:16} {np.median(cn):8.2%} / {max(cn):6.2%} "
                  f"{np.mean([r['cn_cover'] for r in res]):9.0%} "
                  f"{max(r['cp_err'] for r in res):13.2%} "
                  f"{sum(r['cp_consistent'] for r in res):>9}/{len(res)} "
                  f"{sum(r['b_covers'] for r in res):>8}/{len(res)} "
                  f"{np.median(eff):8.2%} / {max(eff):6.2%} "
                  f"{np.mean([r['eff_cover'] for r in res]):16.0%}")


if __name__ == "__main__":
    main_()
