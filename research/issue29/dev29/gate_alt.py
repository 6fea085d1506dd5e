"""bias29: alternative gates of the mean term, in-process on the dev runs (diagnosis only).

global : the shipped g(z) = beta z gate(|z|; z0, s), y_mean a constant
per_cmd: the same form fitted per command level (an upper bound on what speed-aware
         gating can gain; y_mean per level too)
deficit: the gate on the current deficit |z| I_hat(n) / f_n(n) (A), whose noise does not
         depend on speed, instead of on |z| (N)

    PYTHONPATH=WORKTREE python gate_alt.py WORK [variant ...]
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from diag import held_out, train, trainings
from scipy.optimize import least_squares

from rigtool.analysis.gp import fit_gated_mean
from rigtool.models import laws
from rigtool.models.qctm import gate


def deficit(betm, x: np.ndarray) -> np.ndarray:  # noqa: ANN001
    n = x[:, 0]
    fn = betm.speed_estimate(n)
    ih = laws.current_from_speed(np.abs(n), betm.c_n, betm.i_0)
    return np.where(np.abs(fn) > 1e-9, np.abs(x[:, 1]) * ih / np.maximum(np.abs(fn), 1e-9), 0.0)


def fit_deficit(z, d, y, w):  # noqa: ANN001, ANN201
    sw = np.sqrt(w)
    best = None
    top = float(np.max(d))
    for q in (0.5, 0.75, 0.9):
        d0 = float(np.quantile(d, q))
        beta0 = float(np.sum(w * z * y) / np.sum(w * z * z))
        f = least_squares(lambda c: sw * (c[0] * z * gate(d, c[1], c[2]) - y), [beta0, d0, 0.25 * d0 + 1e-3],
                          bounds=([-np.inf, 0, 1e-4], [np.inf, top, top]))
        if best is None or f.cost < best.cost:
            best = f
    b, d0, s = best.x
    return lambda zz, dd: b * zz * gate(dd, d0, s), (b, d0, s)


def main() -> None:
    work = Path(sys.argv[1])
    for store, v, r, name, t in trainings(work, sys.argv[2:]):
        betm, pool, sel = train(store, t["base"], t["train"])
        hs = [held_out(store, betm, rid) for rid in r["test"]]
        xf = np.concatenate([h.xf for h in hs])
        y = np.concatenate([h.y for h in hs])
        cls = np.concatenate([h.block_class for h in hs])
        cmd = np.concatenate([h.command for h in hs])
        ev, ou = cls == "event", cls == "outside"
        preds = {}
        g = fit_gated_mean(sel.xf[:, 1], sel.y, sel.w)
        preds["global"] = np.mean(sel.y - g(sel.xf[:, 1])) + g(xf[:, 1])
        pc = np.zeros(len(y))
        for c in np.unique(cmd):
            m, mt = sel.command == c, cmd == c
            gc = fit_gated_mean(sel.xf[m, 1], sel.y[m], sel.w[m])
            pc[mt] = np.mean(sel.y[m] - gc(sel.xf[m, 1])) + gc(xf[mt, 1])
        preds["per_cmd"] = pc
        f, par = fit_deficit(sel.xf[:, 1], deficit(betm, sel.xf), sel.y, sel.w)
        preds["deficit"] = np.mean(sel.y - f(sel.xf[:, 1], deficit(betm, sel.xf))) + \
            f(xf[:, 1], deficit(betm, xf))
        for k, p in preds.items():
            e = p - y
            by = {f"{c:.0f}": (round(float(e[ev & (cmd == c)].mean()), 2),
                               round(float(np.sqrt(np.mean(e[ev & (cmd == c)] ** 2))), 2),
                               round(float(e[ou & (cmd == c)].mean()), 2),
                               round(float(np.sqrt(np.mean(e[ou & (cmd == c)] ** 2))), 2))
                  for c in np.unique(cmd)}
            print(f"{v:5} {name:9} {k:8} ev bias {e[ev].mean():+.2f} rms {np.sqrt(np.mean(e[ev]**2)):.2f}"
                  f" | out bias {e[ou].mean():+.3f} rms {np.sqrt(np.mean(e[ou]**2)):.3f} | per cmd "
                  f"(ev bias, ev rms, out bias, out rms) {by}" + (f" par {np.round(par, 3)}" if k == "deficit" else ""),
                  flush=True)


if __name__ == "__main__":
    main()
