"""bias29: the mean term's error during TRUE events by time since the event start and before
its end (hypothesis d: event edges and the 0.4 s lead of the centred 1 s window), on the
held-out runs of each training; blocks within 0.5 s of a point start are left out.

    PYTHONPATH=WORKTREE:. python edges.py WORK [variant ...]
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from diag import held_out, train, trainings, truth

from rigtool.analysis.gp import fit_gated_mean

BINS_S = (0.0, 0.3, 0.5, 1.0, 2.0, np.inf)


def main() -> None:
    work = Path(sys.argv[1])
    for store, v, r, name, t in trainings(work, sys.argv[2:]):
        betm, _pool, sel = train(store, t["base"], t["train"])
        g = fit_gated_mean(sel.xf[:, 1], sel.y, sel.w)
        y_mean = float(np.mean(sel.y - g(sel.xf[:, 1])))
        since, until, err, cmd = [], [], [], []
        for rid in r["test"]:
            h = held_out(store, betm, rid)
            ev = truth(store, rid)
            s = np.full(len(h), np.nan)
            u = np.full(len(h), np.nan)
            for e in ev:
                m = (h.t_s >= e.t_start_s) & (h.t_s <= e.t_end_s)
                s[m], u[m] = h.t_s[m] - e.t_start_s, e.t_end_s - h.t_s[m]
            ok = np.isfinite(s) & (np.asarray(h.block_class) != "step")
            since.append(s[ok]), until.append(u[ok]), cmd.append(h.command[ok])
            err.append((y_mean + g(h.xf[:, 1]) - h.y)[ok])
        s, u, e, c = (np.concatenate(a) for a in (since, until, err, cmd))
        for label, lv in (("40 %", c < 50), ("69/90 %", c >= 50)):
            row = []
            for a, b in zip(BINS_S[:-1], BINS_S[1:], strict=True):
                ms, mu = lv & (s >= a) & (s < b), lv & (u >= a) & (u < b)
                row.append(f"[{a:g},{b:g}) s start {e[ms].mean():+.2f} (n {ms.sum()}) "
                           f"end {e[mu].mean():+.2f} (n {mu.sum()})")
            print(f"{v:5} {name:9} {label:8}", " | ".join(row), flush=True)


if __name__ == "__main__":
    main()
