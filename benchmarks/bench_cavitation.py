"""Acceptance table of the QCTM-GP on held-out twin runs of luo2020-cavitation.

    python benchmarks/bench_cavitation.py [--train 11 12] [--test 21 ... 28] [--budget 2000]
        [--causal] [--db FILE]

The defaults give the figures in docs/cavitation.md (`--causal` for the causal-window ones).

Records a deep baseline run and cavitation runs (seeds given) into a temporary database, trains
BETM + GP on the --train seeds and prints errors, coverage and event matching on the --test
seeds (never used for training), plus error vs training-set size.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from rigtool.analysis.cavitation import (
    CavitationParams,
    build_betm,
    evaluate_on_run,
    predictor,
    train_model,
)
from rigtool.analysis.dataset import load_run
from rigtool.store import Store

ROOT = Path(__file__).resolve().parents[1]


def sweep(db: Path, protocol: str, seed: int | None) -> str:
    """Record one twin run; return its id."""
    cmd = [sys.executable, "-c", "import sys; from rigtool.cli import main; sys.exit(main())", "sweep", str(ROOT / "protocols" / protocol), "--sim",
           "--db", str(db)] + ([] if seed is None else ["--seed", str(seed)])
    subprocess.run(cmd, check=True, capture_output=True)
    return Store(db).runs(limit=1)[0]["id"]


def table(store: Store, tests: list[str], betm, gp, p: CavitationParams) -> dict:
    """Pooled class errors over the test runs."""
    rows: dict[str, list] = {}
    match = [0, 0, 0, 0, 0, 0]
    for rid in tests:
        ev = evaluate_on_run(store, rid, predictor(betm, gp, p.window_blocks, p.lead_blocks), betm, p)
        for c in ev.classes:
            rows.setdefault(c.name, []).append(c)
        m = ev.matching
        match = [a + b for a, b in zip(match, (m.n_true, m.n_true_found, m.n_detected, m.n_false,
                                               m.n_true_short, m.n_true_short_found), strict=True)]
    return {"classes": rows, "match": match}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--train", type=int, nargs="+", default=[11, 12])
    ap.add_argument("--test", type=int, nargs="+", default=list(range(21, 29)))
    ap.add_argument("--budget", type=int, default=2000)
    ap.add_argument("--sizes", type=int, nargs="*", default=[250, 500, 1000, 2000, 3000])
    ap.add_argument("--db", help="reuse this database (created if missing)")
    ap.add_argument("--causal", action="store_true",
                    help="shortfall window of past blocks only (what a controller can compute)")
    args = ap.parse_args()
    db = Path(args.db) if args.db else Path(tempfile.mkdtemp()) / "cav.sqlite"
    base = sweep(db, "luo2020-baseline.yaml", None)
    train = [sweep(db, "luo2020-cavitation.yaml", s) for s in args.train]
    tests = [sweep(db, "luo2020-cavitation.yaml", s) for s in args.test]
    store = Store(db)
    p = CavitationParams(budget=args.budget, causal=args.causal)
    _, deep_blocks, deep_samples = build_betm(load_run(store, base), p)
    print("BETM on deep points of the base run (odd points; C_i and variances from even points):")
    for label, errors in ((f"{p.train_block_s:g} s blocks", deep_blocks), ("samples", deep_samples)):
        for e in errors:
            print(f"  {label:10} {e.name:36} max {e.max_abs_n:5.2f} N  p95 {e.p95_abs_n:5.2f} N  "
                  f"rms {e.rms_n:6.4f} N  within 1 N {e.within_1n:6.1%}")
    t0 = time.perf_counter()
    betm, gp, ts = train_model(store, train, base, p)
    print(f"trained on seeds {args.train} ({len(ts)} blocks) in {time.perf_counter() - t0:.1f} s; "
          f"held-out seeds {args.test}")
    res = table(store, tests, betm, gp, p)
    print(f"{'class':8} {'n':>6} {'p95 |e| N':>10} {'max |e| N':>10} {'rms N':>7} {'cover95':>8}  max at")
    for name, cs in res["classes"].items():
        n = sum(c.n for c in cs)
        p95 = max(c.p95_abs_n for c in cs)
        worst = max(cs, key=lambda c: c.max_abs_n)
        cov = sum(c.coverage95 * c.n for c in cs) / n
        rms = float(np.sqrt(sum(c.rms_n**2 * c.n for c in cs) / n))
        print(f"{name:8} {n:6d} {p95:10.2f} {worst.max_abs_n:10.2f} {rms:7.2f} {cov:8.3f}  "
              f"{worst.max_at}")
    nt, nf, nd, nfa, ns, nsf = res["match"]
    print(f"events: {nf}/{nt} true events found ({nf / max(nt, 1):.1%}), {nfa}/{nd} detected "
          f"false ({nfa / max(nd, 1):.1%}); {ns} true events shorter than the minimum duration "
          f"({nsf} of them found)")
    print("(p95 column: worst held-out run; coverage pooled)")
    print("\nerror vs training-set size (pooled held-out blocks):")
    print(f"{'budget':>7} {'fit s':>6} {'p95 event':>10} {'p95 outside':>12} {'cover95':>8}")
    for size in args.sizes:
        q = replace(p, budget=size)
        t0 = time.perf_counter()
        b2, g2, ts2 = train_model(store, train, base, q)
        dt = time.perf_counter() - t0
        r = table(store, tests, b2, g2, q)["classes"]
        cov_all = sum(c.coverage95 * c.n for c in r["all"]) / sum(c.n for c in r["all"])
        print(f"{len(ts2):7d} {dt:6.1f} {max(c.p95_abs_n for c in r['event']):10.2f} "
              f"{max(c.p95_abs_n for c in r['outside']):12.2f} {cov_all:8.3f}")


if __name__ == "__main__":
    main()
