"""Benchmark: do the 95 % intervals cover the truth at their rate, without wasted width?

Three suites, each a set of cells (one known truth, many noise seeds):

- `twin`: a reduced luo2020-baseline (-100..100 % in 2 % steps, 1500 samples per point) swept on
  three CAN twins, calibrated with the systematic allowance set to 0.
- `tables`: files of known truth in the formats `rigtool import` reads (tests/importdata.py:
  manufacturer tables with the textbook current law, Tyto/RCbenchmark logs) and T200-like
  maker tables (tests/tabledata.py: current exponent 3.2-3.6, current printed in 0.01-0.1 A
  steps), imported and calibrated the same way.
- `voltage`: T200-like tables of six supply voltages in one file (`Supply Voltage (V)`), with
  C_p the same at every voltage: how often a false "C_p differs" warning appears.

Per cell and coefficient it prints the coverage of the statistical interval, the mean
half-width over the scatter of the estimates across seeds (about 1.96 when the intervals are
honest and no wider than they need to be), the bias over the scatter and the worst error. It
also counts the current-law warnings (expected on the T200-like cells only) and checks that
no efficiency is reported below the power floor. Seeds default to a held-out range.

    python benchmarks/bench_coverage.py [--suite twin,tables,voltage] [--seeds 40]
                                        [--first-seed 7000] [--thrusters 3]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from rigtool.analysis.calibrate import calibrate_run  # noqa: E402
from rigtool.analysis.depth_fits import FitParams  # noqa: E402
from rigtool.analysis.efficiency import efficiency_n_per_w  # noqa: E402
from rigtool.analysis.results import CalibrationParams  # noqa: E402
from rigtool.cli import main  # noqa: E402
from rigtool.store import Store  # noqa: E402
from rigtool.thruster_profiles import PROFILES  # noqa: E402
from tests import importdata, tabledata  # noqa: E402

CAN = PROFILES["can-bldc"]
# (cp_forward, cp_reverse, cn): the stock twin and two others, as in the acceptance tests.
THRUSTERS = [(CAN.cp_forward, CAN.cp_reverse, CAN.cn), (2.6e-5, 0.75 * 2.6e-5, 0.9e-9),
             (1.4e-5, 0.75 * 1.4e-5, 1.8e-9)]
NAMES = ("C_p_fwd", "C_p_rev", "C_n", "C_i_fwd", "C_i_rev", "C_i_fwd_direct", "C_i_rev_direct",
         "k_free")
LAW_WARNING = "current law"
PARAMS = CalibrationParams(fit=FitParams(rel_systematic=0.0))
# How a user maps a T200 table (its `Supply Voltage (V)` column is left to be recognised).
T200_ARGS = ["--col", "command=PWM", "--col", "speed=RPM", "--col", "current=Current",
             "--col", "voltage=Voltage", "--col", "thrust=Force", "--unit", "thrust=kgf",
             "--command-unit", "pulse_us"]


@dataclass
class Outcome:
    """One calibrated seed: {name: (value, stat_lo, stat_hi)}, its warnings and efficiency."""

    coef: dict[str, tuple[float, float, float]]
    warnings: list[str]
    eff_ok: bool = True  # no efficiency reported below the power floor


@dataclass
class Cell:
    """A known truth and how to make and calibrate one noise seed of it."""

    name: str
    truth: dict[str, float]
    run: Callable[[Path, int], Outcome]


def quiet(argv: list[str]) -> None:
    """Run the CLI with its output swallowed; raise if it fails."""
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        if main(argv) != 0:
            raise RuntimeError(f"rigtool {' '.join(argv[:2])} failed")


def calibrate_last(db: Path) -> Outcome:
    """Calibrate the last run of `db` without the systematic allowance."""
    store = Store(db)
    try:
        cal = calibrate_run(store, store.resolve_run_id("last"), PARAMS)
    finally:
        store.close()
    sec = cal.sections[len(cal.sections) // 2]
    coef = {k: (c.value, *c.statistical) for k, c in sec.fits.items()}
    return Outcome(coef, list(cal.warnings), all(_eff_ok(s.points) for s in cal.sections))


def _eff_ok(points: object) -> bool:
    """No finite efficiency at a point below its power floor."""
    eff = efficiency_n_per_w(points)  # type: ignore[arg-type]
    floor = getattr(points, "power_floor_w", np.zeros(0))
    if floor.size != eff.size:
        return True
    return not bool(np.any(np.isfinite(eff) & (points.power.mean < floor)))  # type: ignore[attr-defined]


# -- the CAN twin ------------------------------------------------------------------------------

def twin_truth(cp_fwd: float, cp_rev: float, cn: float) -> dict[str, float]:
    ci_f, ci_r = cp_fwd / cn ** (2 / 3), cp_rev / cn ** (2 / 3)
    return {"C_p_fwd": cp_fwd, "C_p_rev": cp_rev, "C_n": cn, "C_i_fwd": ci_f,
            "C_i_rev": ci_r, "C_i_fwd_direct": ci_f, "C_i_rev_direct": ci_r, "k_free": 3.0}


def twin_cell(index: int, thruster: tuple[float, float, float]) -> Cell:
    cp_f, cp_r, cn = thruster

    def run(folder: Path, seed: int) -> Outcome:
        protocol = (ROOT / "protocols" / "luo2020-baseline.yaml").read_text()
        protocol = protocol.replace("step: 0.5}", "step: 2}").replace("samples: 3000",
                                                                       "samples: 1500")
        protocol = protocol.replace("seed: 2020", f"seed: {seed}\n  overrides: "
                                    f"{{cp_forward: {cp_f}, cp_reverse: {cp_r}, cn: {cn}}}")
        path = folder / f"p{seed}.yaml"
        path.write_text(protocol)
        db = folder / f"r{seed}.sqlite"
        quiet(["sweep", str(path), "--sim", "--db", str(db)])
        return calibrate_last(db)

    return Cell(f"twin {index}", twin_truth(*thruster), run)


# -- imported files ----------------------------------------------------------------------------

def import_and_calibrate(folder: Path, text: str, args: list[str], seed: int) -> Outcome:
    path, db = folder / f"t{seed}.csv", folder / f"t{seed}.sqlite"
    path.write_text(text, encoding="utf-8")
    quiet(["import", str(path), "--db", str(db), *args])
    return calibrate_last(db)


def cubic_truth(th: importdata.TwoWayThruster) -> dict[str, float]:
    ci_f, ci_r = th.cp_fwd / th.cn ** (2 / 3), th.cp_rev / th.cn ** (2 / 3)
    return {"C_p_fwd": th.cp_fwd, "C_p_rev": th.cp_rev, "C_n": th.cn, "C_i_fwd": ci_f,
            "C_i_rev": ci_r, "C_i_fwd_direct": ci_f, "C_i_rev_direct": ci_r, "k_free": 3.0}


def maker_cell(param_seed: int, **fixed: object) -> Cell:
    """A manufacturer table of the textbook law (tests/importdata.py maker_table)."""
    base = importdata.random_thruster(param_seed, **fixed)

    def run(folder: Path, seed: int) -> Outcome:
        th = replace(base, seed=seed)
        return import_and_calibrate(folder, importdata.maker_table(th),
                                    importdata.maker_table_args(th), seed)

    label = ", ".join(f"{k}={v}" for k, v in fixed.items())
    return Cell(f"maker table {param_seed} ({label})", cubic_truth(base), run)


def stand_cell(param_seed: int, **options: object) -> Cell:
    """A Tyto/RCbenchmark time series (tests/importdata.py stand_log)."""
    base = importdata.random_thruster(param_seed, unit="pulse_us")

    def run(folder: Path, seed: int) -> Outcome:
        th = replace(base, seed=seed)
        return import_and_calibrate(folder, importdata.stand_log(th, **options),
                                    ["--settle-s", "1"], seed)

    label = "averaged steps" if options.get("averaged") else "time series"
    return Cell(f"stand log {param_seed} ({label})", cubic_truth(base), run)


def t200_truth(th: tabledata.MakerThruster, volts: float) -> dict[str, float]:
    """The coefficients of the table at `volts`; C_i at the true exponent (N/A^(2/k))."""
    out = {"C_p_fwd": th.cp_fwd, "C_p_rev": th.cp_rev, "k_free": th.k,
           "C_i_fwd": th.ci(volts), "C_i_rev": th.ci(volts, "rev"),
           "C_i_fwd_direct": th.ci(volts), "C_i_rev_direct": th.ci(volts, "rev")}
    return out | ({"C_n": th.c_law(volts)} if th.k == 3.0 else {"I_0_free": th.i0_a})


def t200_cell(param_seed: int, voltages: tuple[float, ...] = (16.0,), **fixed: object) -> Cell:
    """A T200-like maker table (tests/tabledata.py), columns mapped as a user would."""
    base = tabledata.random_maker(param_seed, **fixed)
    mid = voltages[len(voltages) // 2]  # the section calibrate_last reads

    def run(folder: Path, seed: int) -> Outcome:
        th = replace(base, seed=seed)
        return import_and_calibrate(folder, tabledata.table(th, voltages), T200_ARGS, seed)

    kind = f"k={base.k:.2f}" + (f", {len(voltages)} voltages" if len(voltages) > 1 else "")
    return Cell(f"T200-like {param_seed} ({kind})", t200_truth(base, mid), run)


def table_cells(first: int, n: int) -> list[Cell]:
    """Three cells per unit of `n`: textbook-law tables and logs, then T200-like tables."""
    cells = [maker_cell(first + 1, unit="pulse_us"),
             maker_cell(first + 2, unit="percent", mirrored=True),
             maker_cell(first + 3, unit="pulse_us", spread=True),
             stand_cell(first + 4), stand_cell(first + 5, averaged=True),
             t200_cell(first + 6), t200_cell(first + 7), t200_cell(first + 8, k=3.0),
             t200_cell(first + 9, k=3.0)]
    return cells[:max(n, 1) * 3]


VOLTS = (10.0, 12.0, 14.0, 16.0, 18.0, 20.0)
SUITES: dict[str, Callable[[int, int], list[Cell]]] = {
    "twin": lambda first, n: [twin_cell(i, t) for i, t in enumerate(THRUSTERS[:n])],
    "tables": table_cells,
    "voltage": lambda first, n: [t200_cell(first + 10 + i, voltages=VOLTS)
                                 for i in range(max(n - 1, 1))],
}


# -- summary -----------------------------------------------------------------------------------

def summarise(cell: Cell, rows: list[Outcome]) -> list[tuple[str, float, float]]:
    """Print one cell's table; return (name, coverage, half-width/scatter) per coefficient."""
    print(f"{cell.name}: {len(rows)} seeds")
    print(f"  {'coefficient':16s} {'coverage':>9s} {'hw/sd':>7s} {'bias/sd':>8s} "
          f"{'worst |err| %':>14s}")
    out = []
    for name, true in cell.truth.items():
        got = np.array([r.coef[name] for r in rows if name in r.coef])
        if got.size == 0:
            continue
        value, lo, hi = got.T
        cover = float(np.mean((lo <= true) & (true <= hi)))
        sd = float(np.std(value, ddof=1))
        ratio = float(np.mean((hi - lo) / 2)) / sd if sd > 0 else float("nan")
        bias = (float(np.mean(value)) - true) / sd if sd > 0 else float("nan")
        worst = float(np.max(np.abs(value / true - 1))) * 100
        out.append((name, cover, ratio))
        print(f"  {name:16s} {cover:9.1%} {ratio:7.2f} {bias:8.2f} {worst:14.3f}")
    law = sum(any(LAW_WARNING in w for w in r.warnings) for r in rows)
    differs = sum(any("C_p_fwd differs" in w for w in r.warnings) for r in rows)
    floor = sum(not r.eff_ok for r in rows)
    print(f"  current-law warning in {law}/{len(rows)}, C_p-differs warning in {differs}/"
          f"{len(rows)}, efficiency below the power floor in {floor}/{len(rows)}")
    return out


def overall(results: list[tuple[str, float, float]]) -> None:
    """Per coefficient over the cells, then over everything: the typical (median) and the
    worst coverage and half-width/scatter."""
    if not results:
        return
    print(f"  {'coefficient':16s} {'cells':>5s} {'coverage median (worst..best)':>30s} "
          f"{'hw/sd median (range)':>22s}")
    for name in dict.fromkeys(n for n, _, _ in results):
        cover = np.array([c for n, c, _ in results if n == name])
        ratio = np.array([r for n, _, r in results if n == name and np.isfinite(r)])
        print(f"  {name:16s} {cover.size:5d} {np.median(cover):12.1%} ({cover.min():.1%}.."
              f"{cover.max():.1%}) {np.median(ratio):9.2f} ({ratio.min():.2f}-{ratio.max():.2f})")
    cover = np.array([c for _, c, _ in results])
    ratio = np.array([r for _, _, r in results if np.isfinite(r)])
    print(f"all cells ({cover.size}): coverage median {np.median(cover):.1%}, worst "
          f"{cover.min():.1%}, best {cover.max():.1%}, 100 % in {int(np.sum(cover == 1))}; "
          f"hw/sd median {np.median(ratio):.2f}, range {ratio.min():.2f}-{ratio.max():.2f}")


def main_() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--suite", default="twin,tables,voltage")
    ap.add_argument("--seeds", type=int, default=40)
    ap.add_argument("--first-seed", type=int, default=7000)
    ap.add_argument("--thrusters", type=int, default=len(THRUSTERS),
                    help="twin suite: twins to run (tables: cells / 3, voltage: cells + 1)")
    ap.add_argument("--param-seed", type=int, default=8100,
                    help="tables and voltage suites: the cells' thrusters are drawn from "
                         "this seed on (development used 6100)")
    ap.add_argument("--json", help="also write every outcome to this file")
    args = ap.parse_args()
    results, dump = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        for suite in args.suite.split(","):
            for cell in SUITES[suite](args.param_seed, args.thrusters):
                rows = []
                for i in range(args.seeds):
                    folder = Path(tmp) / f"{suite}-{len(results)}-{i}"
                    folder.mkdir()
                    rows.append(cell.run(folder, args.first_seed + i))
                results += summarise(cell, rows)
                dump[cell.name] = {"truth": cell.truth, "rows": [r.__dict__ for r in rows]}
    overall(results)
    if args.json:
        Path(args.json).write_text(json.dumps(dump, indent=1, default=float))


if __name__ == "__main__":
    main_()
