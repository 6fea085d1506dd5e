"""bias29: the gate width s floored at the z noise (sqrt(3)/pi x robust sd of z on blocks
outside detected events: a logistic as wide as the measurement noise), in-process.

    PYTHONPATH=WORKTREE:. python sfloor.py WORK [variant ...]
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from diag import held_out, train, trainings
from scipy.optimize import least_squares

from rigtool.analysis.gp import fit_gated_mean
from rigtool.models.qctm import GatedMean


def floored(z: np.ndarray, y: np.ndarray, w: np.ndarray, s_min: float) -> GatedMean:
    g = fit_gated_mean(z, y, w)
    if g.s <= 0 or g.s >= s_min:
        return g
    sw = np.sqrt(w)
    fit = least_squares(lambda c: sw * (GatedMean(c[0], c[1], s_min)(z) - y), [g.beta, g.z0],
                        bounds=([-np.inf, 0.0], [np.inf, float(np.abs(z).max())]))
    return GatedMean(float(fit.x[0]), float(fit.x[1]), s_min)


def main() -> None:
    work = Path(sys.argv[1])
    for store, v, r, name, t in trainings(work, sys.argv[2:]):
        betm, _pool, sel = train(store, t["base"], t["train"])
        zq = sel.xf[~sel.ventilated, 1]
        sd = 1.4826 * float(np.median(np.abs(zq - np.median(zq))))
        s_min = np.sqrt(3) / np.pi * sd
        hs = [held_out(store, betm, rid) for rid in r["test"]]
        z = np.concatenate([h.xf[:, 1] for h in hs])
        y = np.concatenate([h.y for h in hs])
        cls = np.concatenate([h.block_class for h in hs])
        ev, ou = cls == "event", cls == "outside"
        for how, g in (("main", fit_gated_mean(sel.xf[:, 1], sel.y, sel.w)),
                       ("floor", floored(sel.xf[:, 1], sel.y, sel.w, s_min))):
            e = np.mean(sel.y - g(sel.xf[:, 1])) + g(z) - y
            print(f"{v:5} {name:9} {how:5} s_min {s_min:.3f} beta {g.beta:.2f} z0 {g.z0:.3f} s {g.s:.3f}"
                  f" | ev bias {e[ev].mean():+.2f} rms {np.sqrt(np.mean(e[ev]**2)):.2f} p95 "
                  f"{np.quantile(np.abs(e[ev]), .95):.2f} | out bias {e[ou].mean():+.3f} rms "
                  f"{np.sqrt(np.mean(e[ou]**2)):.3f} p95 {np.quantile(np.abs(e[ou]), .95):.2f}", flush=True)


if __name__ == "__main__":
    main()
