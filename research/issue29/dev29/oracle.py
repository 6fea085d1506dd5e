"""bias29: how far a mean from these signals can follow TRUE ventilation (diagnosis only).

Per training, on its held-out runs: the exported mean term's error during true events per
command level, next to the error of an in-sample optimum E[y | z, command], fitted on the
held-out blocks themselves by 20 quantile bins of z per command level (it knows the
held-out data, so it is optimistic), and the separation of z between true event blocks
and outside blocks per command (d' = mean difference / outside sd; AUC).

    PYTHONPATH=WORKTREE:. python oracle.py WORK [variant ...]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from diag import held_out, train, trainings

from rigtool.analysis.gp import fit_gated_mean


def binned_mean(z: np.ndarray, y: np.ndarray, bins: int = 20) -> np.ndarray:
    edges = np.unique(np.quantile(z, np.linspace(0, 1, bins + 1)))
    k = np.clip(np.searchsorted(edges, z, side="right") - 1, 0, edges.size - 2)
    means = np.array([y[k == j].mean() if (k == j).any() else 0.0 for j in range(edges.size - 1)])
    return means[k]


def auc(a: np.ndarray, b: np.ndarray) -> float:
    r = np.argsort(np.argsort(np.concatenate([a, b])))
    return float((r[: a.size].sum() - a.size * (a.size - 1) / 2) / (a.size * b.size))


def main() -> None:
    work = Path(sys.argv[1])
    rows = {}
    for store, v, r, name, t in trainings(work, sys.argv[2:]):
        betm, _pool, sel = train(store, t["base"], t["train"])
        hs = [held_out(store, betm, rid) for rid in r["test"]]
        z = np.concatenate([h.xf[:, 1] for h in hs])
        y = np.concatenate([h.y for h in hs])
        cls = np.concatenate([h.block_class for h in hs])
        cmd = np.concatenate([h.command for h in hs])
        g = fit_gated_mean(sel.xf[:, 1], sel.y, sel.w)
        model = np.mean(sel.y - g(sel.xf[:, 1])) + g(z)
        use = (cls == "event") | (cls == "outside")
        best = np.full(y.size, np.nan)
        for c in np.unique(cmd):
            m = use & (cmd == c)
            best[m] = binned_mean(z[m], y[m])
        ev, ou = cls == "event", cls == "outside"
        out = {}
        for c in np.unique(cmd[ev]):
            e, o = ev & (cmd == c), ou & (cmd == c)
            out[f"{c:.0f}"] = {
                "n_ev": int(e.sum()), "model_ev": round(float((model - y)[e].mean()), 2),
                "best_ev": round(float((best - y)[e].mean()), 2),
                "model_out": round(float((model - y)[o].mean()), 2),
                "best_out": round(float((best - y)[o].mean()), 2),
                "true_loss": round(float(-y[e].mean()), 2),
                "dprime": round(float((np.abs(z[e]).mean() - np.abs(z[o]).mean()) / np.abs(z[o]).std()), 2),
                "auc": round(auc(np.abs(z[e]), np.abs(z[o])), 3)}
        tot = {"model_ev": float((model - y)[ev].mean()), "best_ev": float((best - y)[ev].mean()),
               "model_out": float((model - y)[ou].mean()), "best_out": float((best - y)[ou].mean())}
        rows[f"{v}-{name}"] = {"total": tot, "by_cmd": out}
        print(f"{v:5} {name:9} event bias model {tot['model_ev']:+.2f} in-sample best {tot['best_ev']:+.2f} "
              f"| outside model {tot['model_out']:+.2f} best {tot['best_out']:+.2f}", flush=True)
        for c, d in out.items():
            print(f"      cmd {c}: {d}", flush=True)
    (work / "oracle.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
