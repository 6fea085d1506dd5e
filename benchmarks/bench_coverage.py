"""Benchmark: do the 95 % intervals of C_p, C_n and C_i cover the twin's truth at their rate?

Sweeps a reduced luo2020-baseline (-100..100 % in 2 % steps, 1500 samples per point) on the
CAN twin for each thruster and seed, calibrates it with the systematic allowance set to 0,
and counts how often the statistical interval holds the value the twin was built with. It
also prints, per coefficient, the mean interval half-width over the scatter of the values
across seeds (about 1.96 when the intervals are honest). Seeds default to a held-out range
not used while developing the fits (dev seeds were 100-139).

    python benchmarks/bench_coverage.py [--seeds 40] [--first-seed 7000] [--thrusters 3]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import tempfile
from pathlib import Path

import numpy as np

from rigtool.analysis.calibrate import CalibrationParams, calibrate_run
from rigtool.analysis.models import FitParams
from rigtool.cli import main
from rigtool.sim.profiles import PROFILES
from rigtool.store import Store

ROOT = Path(__file__).resolve().parent.parent
CAN = PROFILES["can-bldc"]
# (cp_forward, cp_reverse, cn): the stock twin and two others, as in the acceptance tests.
THRUSTERS = [(CAN.cp_forward, CAN.cp_reverse, CAN.cn), (2.6e-5, 0.75 * 2.6e-5, 0.9e-9),
             (1.4e-5, 0.75 * 1.4e-5, 1.8e-9)]
NAMES = ("C_p_fwd", "C_p_rev", "C_n", "C_i_fwd", "C_i_rev", "C_i_fwd_direct", "C_i_rev_direct")


def truth(cp_fwd: float, cp_rev: float, cn: float) -> dict[str, float]:
    ci_f, ci_r = cp_fwd / cn ** (2 / 3), cp_rev / cn ** (2 / 3)
    return {"C_p_fwd": cp_fwd, "C_p_rev": cp_rev, "C_n": cn, "C_i_fwd": ci_f,
            "C_i_rev": ci_r, "C_i_fwd_direct": ci_f, "C_i_rev_direct": ci_r}


def one_run(folder: Path, thruster: tuple[float, float, float], seed: int) -> dict:
    """Sweep and calibrate one seed; {name: (value, lo, hi)} with no systematic allowance."""
    cp_f, cp_r, cn = thruster
    protocol = (ROOT / "protocols" / "luo2020-baseline.yaml").read_text()
    protocol = protocol.replace("step: 0.5}", "step: 2}").replace("samples: 3000", "samples: 1500")
    protocol = protocol.replace("seed: 2020", f"seed: {seed}\n  overrides: "
                                f"{{cp_forward: {cp_f}, cp_reverse: {cp_r}, cn: {cn}}}")
    path = folder / f"p{seed}.yaml"
    path.write_text(protocol)
    db = folder / f"r{seed}.sqlite"
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        if main(["sweep", str(path), "--sim", "--db", str(db)]) != 0:
            raise RuntimeError(f"sweep of seed {seed} failed")
    store = Store(db)
    try:
        params = CalibrationParams(fit=FitParams(rel_systematic=0.0))
        (sec,) = calibrate_run(store, store.resolve_run_id("last"), params).sections
    finally:
        store.close()
    return {k: (sec.fits[k].value, sec.fits[k].lo, sec.fits[k].hi) for k in NAMES
            if k in sec.fits}


def main_() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=40)
    ap.add_argument("--first-seed", type=int, default=7000)
    ap.add_argument("--thrusters", type=int, default=len(THRUSTERS))
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for t_index, thruster in enumerate(THRUSTERS[:args.thrusters]):
            true = truth(*thruster)
            rows = [one_run(Path(tmp), thruster, args.first_seed + i) for i in range(args.seeds)]
            print(f"thruster {t_index}: C_p fwd {thruster[0]:.4g}, rev {thruster[1]:.4g}, "
                  f"C_n {thruster[2]:.4g}; {args.seeds} seeds from {args.first_seed}")
            print(f"  {'coefficient':16s} {'coverage':>9s} {'hw/sd':>7s} {'bias/sd':>8s} "
                  f"{'worst |err| %':>14s}")
            for name in NAMES:
                got = np.array([r[name] for r in rows if name in r])
                if got.size == 0:
                    continue
                value, lo, hi = got.T
                cover = np.mean((lo <= true[name]) & (true[name] <= hi))
                sd = float(np.std(value, ddof=1))
                hw = float(np.mean((hi - lo) / 2))
                bias = float(np.mean(value) - true[name])
                worst = float(np.max(np.abs(value / true[name] - 1))) * 100
                print(f"  {name:16s} {cover:9.1%} {hw / sd:7.2f} {bias / sd:8.2f} {worst:14.3f}")


if __name__ == "__main__":
    main_()
