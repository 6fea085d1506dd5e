"""Acceptance table of the QCTM-GP over several training combinations and held-out runs.

    python benchmarks/bench_cavitation.py [--set dev|final] [--variant stock|weak] [--runs N]
        [--single] [--causal] [--budget 2000] [--db FILE] [--combos N] [--json FILE]

A combination is a deep base run (luo2020-baseline, its own seed) plus two shallow training
runs (luo2020-cavitation, their own seeds; `--runs N` for N, `--single` for one).
`--variant` picks the twin: `stock` (the can-bldc profile as shipped) or `weak` (another
C_p/C_n, a noisier current and a weaker current signal of ventilation: `VARIANTS`), applied
to every run of the set through the protocols' simulator overrides. Each combination's model is the one `calibrate`
would export (`rigtool.models.ThrustModel`), tested on 8 held-out luo2020-cavitation seeds and
on runs of a depth/command grid outside the protocol. The table reports every combination and
the worst one; coverage is split into during events and outside them.

Disjoint seed sets: `dev`, `dev2` and `dev3` (used while developing the method) and `final` (kept untouched
for the reported figures). Never tune on `final`. The interval calibration (run-fold and
block-fold scaling, docs/cavitation.md) was developed on `cal-dev` (seeds 20xxx) and reported
once on `cal-final` (seeds 80xxx); its own target outside events (OUTSIDE_CHECK_LEVEL) was
chosen on `cal-dev` and reported once on `cal-final2` (seeds 91xxx).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from rigtool.analysis.cavitation import evaluate_on_run, thrust_model, train_model
from rigtool.analysis.gp import SIGNAL_SCALES, GpParams
from rigtool.analysis.results import CavitationParams
from rigtool.models import OUT_OF_DOMAIN
from rigtool.store import Store

ROOT = Path(__file__).resolve().parents[1]
SETS = {
    # (base seed, training seeds) per combination; held-out test seeds; grid seeds
    "dev": ([(101, (111, 112)), (102, (113, 114)), (103, (115, 116)), (104, (117, 118))],
            list(range(121, 129)), [131, 132]),
    "dev2": ([(401, (411, 412)), (402, (413, 414)), (403, (415, 416)), (404, (417, 418))],
             list(range(421, 429)), [431, 432]),
    "dev3": ([(501, (511, 512)), (502, (513, 514)), (503, (515, 516)), (504, (517, 518)),
              (505, (519, 520)), (506, (521, 522))], list(range(531, 539)), [541, 542]),
    # looked at once as the final set (it failed there), since then a development set
    "seen1": ([(301, (311, 312)), (302, (313, 314)), (303, (315, 316)), (304, (317, 318))],
              list(range(321, 329)), [331, 332]),
    # final set 2: looked at once (GP signal chosen by cross-validation failed there)
    "seen2": ([(601, (611, 612)), (602, (613, 614)), (603, (615, 616)), (604, (617, 618))],
              list(range(621, 629)), [631, 632]),
    "final": ([(701, (711, 712)), (702, (713, 714)), (703, (715, 716)), (704, (717, 718))],
              list(range(721, 729)), [731, 732]),
    # interval calibration: developed on cal-dev, reported once on cal-final
    "cal-dev": ([(20000 + 10 * k, tuple(20001 + 10 * k + j for j in range(3))) for k in range(6)],
                list(range(20101, 20109)), [20201, 20202]),
    "cal-final": ([(80000 + 10 * k, tuple(80001 + 10 * k + j for j in range(3)))
                   for k in range(6)], list(range(80101, 80109)), [80201, 80202]),
    # the per-condition interval method: developed on cal-dev, reported once on cal-final2
    "cal-final2": ([(91000 + 10 * k, tuple(91001 + 10 * k + j for j in range(3)))
                    for k in range(6)], list(range(91101, 91109)), [91201, 91202]),
    # the lower-side widening for ventilation the gate misses: developed on cal-dev,
    # reported once on cal-final3
    "cal-final3": ([(93000 + 10 * k, tuple(93001 + 10 * k + j for j in range(3)))
                    for k in range(6)], list(range(93101, 93109)), [93201, 93202]),
    # the episode-conformal event scale: developed on cal-dev, reported once on cal-final4
    "cal-final4": ([(95000 + 10 * k, tuple(95001 + 10 * k + j for j in range(3)))
                    for k in range(6)], list(range(95101, 95109)), [95201, 95202]),
}
# Twin variants (simulator overrides on can-bldc, applied to base, training and test runs).
# `weak`: a bigger propeller on a thriftier motor (other C_p, C_n), a noisier current and
# ventilation that lowers the current by 6 % of the drop instead of 8 %: the current says
# less about the thrust loss than on the stock twin.
VARIANTS: dict[str, dict[str, float]] = {
    "stock": {},
    "weak": {"cp_forward": 2.2e-5, "cp_reverse": 0.8 * 2.2e-5, "cn": 1.0e-9,
             "current_noise_a": 0.22, "cav_current_drop": 0.06},
}
GRID = {"command": {"unit": "percent", "values": [30, 55, 80], "order": "up"},
        "depth": {"unit": "cm", "values": [25, 45], "mode": "manual"}}


def sweep(db: Path, protocol: Path, seed: int) -> str:
    """Record one twin run through the CLI; return its id."""
    cmd = [sys.executable, "-m", "rigtool", "sweep", str(protocol), "--sim", "--db", str(db),
           "--seed", str(seed)]
    subprocess.run(cmd, check=True, capture_output=True)
    return Store(db).runs(limit=1)[0]["id"]


def variant_protocol(folder: Path, name: str, variant: str, changes: dict | None = None) -> Path:
    """A shipped protocol (`name`) on the twin `variant`, renamed `name` + "-" + variant
    unless stock, with top-level `changes`."""
    doc = yaml.safe_load((ROOT / "protocols" / f"{name}.yaml").read_text())
    doc.update(changes or {})
    if VARIANTS[variant]:
        doc["simulator"]["overrides"] = dict(VARIANTS[variant])
        doc["name"] = f"{doc['name']}-{variant}"
    path = folder / f"{doc['name']}.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def grid_protocol(folder: Path, variant: str = "stock") -> Path:
    """luo2020-cavitation with depths and commands it does not contain."""
    return variant_protocol(folder, "luo2020-cavitation", variant,
                            {**GRID, "name": "luo2020-cavitation-grid"})


def pooled(evals: list) -> dict[str, dict]:
    """Per class: worst run's p95, max, pooled coverage and count."""
    out: dict[str, dict] = {}
    for ev in evals:
        for c in ev.classes:
            d = out.setdefault(c.name, {"n": 0, "p95": 0.0, "max": 0.0, "inside": 0.0,
                                        "p95s": []})
            d["n"] += c.n
            d["p95"] = max(d["p95"], c.p95_abs_n)
            d["p95s"].append(c.p95_abs_n)
            d["max"] = max(d["max"], c.max_abs_n)
            d["inside"] += c.coverage95 * c.n
    for d in out.values():
        d["cover"] = d["inside"] / max(d["n"], 1)
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--set", choices=sorted(SETS), default="dev")
    ap.add_argument("--combos", type=int, default=4, help="use the first N combinations")
    ap.add_argument("--only", type=int, nargs="+", help="use the combinations of these base seeds")
    ap.add_argument("--budget", type=int, default=2000)
    ap.add_argument("--db", help="reuse this database (runs are recorded once per seed)")
    ap.add_argument("--verbose", action="store_true", help="print every held-out run's classes")
    ap.add_argument("--gp-signal", choices=("off", "cv"), default="off",
                    help="off: the mean term alone (the default fit); cv: cross-validation over "
                    "the signal-variance factors, 0 included, picks one")
    ap.add_argument("--single", action="store_true",
                    help="train on one run per combination, as `rigtool calibrate RUN` does")
    ap.add_argument("--runs", type=int, default=2, help="training runs per combination")
    ap.add_argument("--variant", choices=sorted(VARIANTS), default="stock")
    ap.add_argument("--json", help="append the per-training figures to this JSON-lines file")
    ap.add_argument("--causal", action="store_true",
                    help="shortfall window of past blocks only (what a controller can compute)")
    args = ap.parse_args()
    combos, test_seeds, grid_seeds = SETS[args.set]
    combos = [c for c in combos if c[0] in args.only] if args.only else combos[:args.combos]
    db = Path(args.db) if args.db else Path(tempfile.mkdtemp()) / "cav.sqlite"
    folder = Path(tempfile.mkdtemp())
    cav = variant_protocol(folder, "luo2020-cavitation", args.variant)
    base_proto = variant_protocol(folder, "luo2020-baseline", args.variant)
    grid = grid_protocol(folder, args.variant)
    known = {(r["name"], r["seed"]): r["id"] for r in _runs(db)}

    def run(protocol: Path, seed: int) -> str:
        name = yaml.safe_load(protocol.read_text())["name"]
        return known.get((name, seed)) or sweep(db, protocol, seed)

    tests = [run(cav, s) for s in test_seeds]
    grids = [run(grid, s) for s in grid_seeds]
    store = Store(db)
    gp_params = GpParams(signal_scales=SIGNAL_SCALES) if args.gp_signal == "cv" else GpParams()
    p = CavitationParams(budget=args.budget, causal=args.causal, gp=gp_params)
    n_runs = 1 if args.single else args.runs
    print(f"set {args.set}, variant {args.variant}, {'causal' if args.causal else 'centred'} "
          f"window, {n_runs} training run(s), GP signal "
          f"{args.gp_signal}, budget {args.budget}; "
          f"held-out seeds {test_seeds}, grid seeds {grid_seeds} (depths 25/45 cm, 30/55/80 %)")
    header = (f"{'base':>5} {'train':>9} {'fit s':>6} | {'p95 ev':>6} {'p95 out':>7} "
              f"{'cov ev':>6} {'cov out':>7} {'cov all':>7} | {'grid p95 ev':>11} "
              f"{'grid p95 out':>12} {'grid cov':>8} | scale  length scales (n, z, h) | "
              "out of domain: held-out, grid")
    print(header)
    rows = []
    for base_seed, train_seeds in combos:
        base = run(base_proto, base_seed)
        train_seeds = train_seeds[:n_runs]
        train = [run(cav, s) for s in train_seeds]
        t0 = time.perf_counter()
        betm, gp, training = train_model(store, train, base, p)
        fit_s = time.perf_counter() - t0
        model = thrust_model(betm, gp, training, p)
        flags: list[np.ndarray] = []

        def predict(n, i, h, segment=None, model=model, flags=flags):  # noqa: ANN001, ANN202
            out = model.evaluate(n, i, h, segment)
            flags.append(out.flags)
            return out.thrust_n, out.lo95, out.hi95

        evals = [evaluate_on_run(store, r, predict, betm, p) for r in tests]
        held = pooled(evals)
        for r, ev in zip(tests, evals, strict=True) if args.verbose else ():
            print("    " + r + "  " + "  ".join(
                f"{c.name} p95 {c.p95_abs_n:.2f} max {c.max_abs_n:.2f} ({c.max_at}) cov "
                f"{c.coverage95:.1%}" for c in ev.classes if c.name in ("event", "outside")))
        held_ood = _ood(flags)
        flags.clear()
        gridres = pooled([evaluate_on_run(store, r, predict, betm, p) for r in grids])
        row = (base_seed, train_seeds, fit_s, held, gridres)
        rows.append(row)
        print(_line(*row) + f" | {gp.signal_scale:g}  "
              + " ".join(f"{v:.3g}" for v in gp.hyper.length_scales)
              + f" | {held_ood:.1%} {_ood(flags):.1%}", flush=True)
        if args.json:
            _append_json(args.json, {"set": args.set, "variant": args.variant, "runs": n_runs,
                                     "causal": args.causal, "base": base_seed,
                                     "train": list(train_seeds), "fit_s": fit_s,
                                     **_figures(held, evals), "grid": _figures(gridres, []),
                                     "check": getattr(gp, "check", None)})
    print("worst over combinations:")
    worst = {k: max(r[3][k]["p95"] for r in rows) for k in ("event", "outside")}
    cover = {k: (min(r[3][k]["cover"] for r in rows), max(r[3][k]["cover"] for r in rows))
             for k in ("event", "outside", "all")}
    print(f"  p95 during events {worst['event']:.2f} N (target <= 3.5), outside "
          f"{worst['outside']:.2f} N (target <= 1)")
    typical = {k: float(np.median([v for r in rows for v in r[3][k]["p95s"]]))
               for k in ("event", "outside")}
    print(f"  typical (median over all held-out runs): p95 during events {typical['event']:.2f} N, "
          f"outside {typical['outside']:.2f} N")
    for k, (lo, hi) in cover.items():
        med = float(np.median([r[3][k]["cover"] for r in rows]))
        print(f"  95 % coverage {k}: {lo:.1%} .. {hi:.1%} over combinations, median {med:.1%} "
              "(target 90-98 %)")
    print("(p95: worst held-out run of a combination; coverage pooled over its runs)")


def _line(base_seed: int, train_seeds: tuple, fit_s: float, held: dict, grid: dict) -> str:
    g = {k: grid.get(k, {"p95": np.nan, "cover": np.nan}) for k in ("event", "outside", "all")}
    return (f"{base_seed:5d} {str(train_seeds):>9} {fit_s:6.1f} | {held['event']['p95']:6.2f} "
            f"{held['outside']['p95']:7.2f} {held['event']['cover']:6.1%} "
            f"{held['outside']['cover']:7.1%} {held['all']['cover']:7.1%} | "
            f"{g['event']['p95']:11.2f} {g['outside']['p95']:12.2f} {g['all']['cover']:8.1%}")


def _figures(held: dict, evals: list) -> dict:
    """Per class (event, outside, all): worst and median run p95, pooled and per-run coverage."""
    out = {}
    for k in ("event", "outside", "all"):
        d = held.get(k)
        runs = [c.coverage95 for ev in evals for c in ev.classes if c.name == k and c.n]
        out[k] = None if d is None else {
            "p95_worst": d["p95"], "p95_median": float(np.median(d["p95s"])),
            "cover": d["cover"], "n": d["n"],
            "cover_runs": [min(runs), max(runs)] if runs else None}
    return out


def _append_json(path: str, record: dict) -> None:
    """One JSON line per training."""
    import json

    with open(path, "a", encoding="utf-8") as fh:
        fh.write(json.dumps(record, default=float) + "\n")


def _ood(flags: list[np.ndarray]) -> float:
    """Fraction of predicted blocks flagged out of the model's domain."""
    f = np.concatenate(flags) if flags else np.zeros(0, int)
    return float(np.mean(f & OUT_OF_DOMAIN)) if f.size else float("nan")


def _runs(db: Path) -> list[dict]:
    """(name, seed, id) of the runs already in `db`."""
    if not db.exists():
        return []
    rows = Store(db).conn.execute("SELECT id, name, seed FROM runs WHERE status = 'completed'")
    return [{"id": r[0], "name": r[1], "seed": r[2]} for r in rows]


if __name__ == "__main__":
    main()
