"""Issue 29 part 3 (bias29): in-process diagnosis of the mean term's error during TRUE
ventilation events on held-out runs (no interval check; the exported mean is
f_BETM + y_mean + g(z), docs/cavitation.md). Reads the runs cav_eval.py recorded.

    PYTHONPATH=WORKTREE python diag.py WORK [variant ...]
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from rigtool.analysis.cavitation import (
    CavitationParams,
    build_betm,
    find_events,
    select,
    training_blocks,
)
from rigtool.analysis.dataset import load_run
from rigtool.analysis.gp import fit_gated_mean
from rigtool.analysis.trainset import concat
from rigtool.models.qctm import gate
from rigtool.store import Store

P = CavitationParams()
VARIANTS = ("sel", "sel-w1", "pool", "pool-w1")


def truth(store: Store, rid: str) -> list:
    return [SimpleNamespace(t_start_s=float(e["detail"]["t_start_s"]),
                            t_end_s=float(e["detail"]["t_end_s"]),
                            drop=float(e["detail"]["drop_frac"]))
            for e in store.events(rid, "sim.ventilation")]


def held_out(store: Store, betm, rid: str):  # noqa: ANN001, ANN201
    ev = truth(store, rid)
    ts, _ = training_blocks(load_run(store, rid), betm, ev, P)
    return ts


def train(store: Store, base: str, runs: list[str]):  # noqa: ANN201
    betm, _, _ = build_betm(load_run(store, base), P)
    sets = []
    for rid in runs:
        run = load_run(store, rid)
        events, _ = find_events(run, betm, P)
        sets.append(training_blocks(run, betm, events, P)[0])
    pool = concat(sets) if len(sets) > 1 else sets[0]
    return betm, pool, select(pool, P.budget)


def trainings(work: Path, twins: list[str]) -> Iterator[tuple[Store, str, dict, str, dict]]:
    """(store, twin, its runs, training name, training) for every training recorded in
    work/runs.json, of the twins named (all when none)."""
    runs = json.loads((work / "runs.json").read_text())
    store = Store(work / "runs.sqlite")
    for v, r in runs.items():
        if twins and v not in twins:
            continue
        for name, t in r["trainings"].items():
            yield store, v, r, name, t


def main() -> None:
    work = Path(sys.argv[1])
    out = {}
    for store, v, r, name, t in trainings(work, sys.argv[2:]):
        betm, pool, sel = train(store, t["base"], t["train"])
        hs = [held_out(store, betm, rid) for rid in r["test"]]
        for how in VARIANTS:
            src = pool if how.startswith("pool") else sel
            ww = np.ones(len(src)) if how.endswith("w1") else src.w
            g = fit_gated_mean(src.xf[:, 1], src.y, ww)
            y_mean = float(np.mean(src.y - g(src.xf[:, 1])))
            name2 = f"{name}/{how}"
            z = np.concatenate([h.xf[:, 1] for h in hs])
            y = np.concatenate([h.y for h in hs])
            cls = np.concatenate([h.block_class for h in hs])
            err = y_mean + g(z) - y
            gt = gate(z, g.z0, g.s)
            ev, ou = cls == "event", cls == "outside"
            row = {"beta": g.beta, "z0": g.z0, "s": g.s, "y_mean": y_mean,
                   "ev_bias": float(err[ev].mean()), "ou_bias": float(err[ou].mean()),
                   "ev_bias_gated": float(err[ev & (gt >= .5)].mean()),
                   "ev_bias_quiet": float(err[ev & (gt < .5)].mean()),
                   "ev_frac_quiet": float(np.mean(gt[ev] < .5)),
                   "ev_rms": float(np.sqrt(np.mean(err[ev] ** 2))),
                   "ou_rms": float(np.sqrt(np.mean(err[ou] ** 2)))}
            # residual by z bins, all held-out event+outside blocks (is E[y|z] right?)
            use = ev | ou
            edges = np.quantile(np.abs(z[use]), [0, .5, .8, .9, .95, .98, 1])
            row["zbins"] = []
            for a, b in zip(edges[:-1], edges[1:], strict=True):
                m = use & (np.abs(z) >= a) & (np.abs(z) <= b)
                row["zbins"].append([round(float(a), 3), round(float(b), 3), int(m.sum()),
                                     round(float(err[m].mean()), 3),
                                     round(float(np.mean(ev[m])), 2)])
            cmd = np.concatenate([h.command for h in hs])
            row["by_cmd"] = {f"{c:.2f}": [round(float(err[ev & (cmd == c)].mean()), 2),
                                          round(float(np.mean(gt[ev & (cmd == c)] < .5)), 2),
                                          round(float(err[ou & (cmd == c)].mean()), 2)]
                             for c in np.unique(cmd[ev])}
            out[f"{v}-{name2}"] = row
            print(f"{v:5} {name2:14} beta {g.beta:7.2f} z0 {g.z0:.3f} s {g.s:.3f} ym {y_mean:+.3f} | "
                  f"ev bias {row['ev_bias']:+.2f} (gated {row['ev_bias_gated']:+.2f}, quiet "
                  f"{row['ev_bias_quiet']:+.2f} frac {row['ev_frac_quiet']:.2f}) rms {row['ev_rms']:.2f}"
                  f" | out bias {row['ou_bias']:+.3f} rms {row['ou_rms']:.2f}", flush=True)
            print("      by command (ev bias, ev quiet frac, out bias):", row["by_cmd"])
            print("      zbins (lo, hi, n, mean err, ev frac):", row["zbins"], flush=True)
    (work / "diag.json").write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
