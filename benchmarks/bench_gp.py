"""GP fit time and memory (tracemalloc peak) vs training-set size, exact GP vs SoR sparse GP.

    python benchmarks/bench_gp.py [--sizes 1000 2000 5000 10000 20000 50000] [--exact-max 8000]

Synthetic data shaped like the QCTM-GP problem (x = speed, current, depth; y = thrust
correction), hyperparameters fitted once on 500 points and then fixed, so the rows compare
the cost of the final fit. The exact GP is skipped above --exact-max points (O(n^2) memory,
O(n^3) time) instead of risking the machine; its limit is reported as "skipped".
"""

from __future__ import annotations

import argparse
import time
import tracemalloc

import numpy as np

from rigtool.analysis.gp import GpParams, Standardiser, fit_exact, fit_hyper, fit_sor


def data(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    depth = rng.choice([0.2, 0.3, 0.4, 0.55], n)
    speed = rng.choice([720.0, 1242.0, 1620.0], n) + rng.normal(0, 3, n)
    drop = np.where(rng.random(n) < 0.4, rng.uniform(0.25, 0.75, n), 0.0)
    current = (1.2e-9 * speed**3 + 0.3) * (1 - 0.08 * drop) + rng.normal(0, 0.015, n)
    y = -1.926e-5 * speed**2 * drop + rng.normal(0, 0.2, n)
    return np.column_stack([speed, current, depth]), y, np.ones(n)


def measure(fn) -> tuple[float, float]:
    tracemalloc.start()
    t0 = time.perf_counter()
    fn()
    dt = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.stop()
    return dt, peak


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", type=int, nargs="+", default=[1000, 2000, 5000, 10000, 20000, 50000])
    ap.add_argument("--exact-max", type=int, default=8000)
    ap.add_argument("--inducing", type=int, default=300)
    args = ap.parse_args()
    x, y, w = data(500, seed=1)
    xs = Standardiser(x)(x)
    t0 = time.perf_counter()
    hyper = fit_hyper(xs, (y - y.mean()) / y.std(), w, GpParams(hyper_n=500, n_restarts=0))
    print(f"hyperparameters on 500 points: {time.perf_counter() - t0:.1f} s")
    xt, yt, _ = data(5000, seed=9)
    print(f"{'n':>6} {'method':>10} {'fit s':>8} {'peak MiB':>9} {'rmse N (5k test)':>17}")
    for n in args.sizes:
        x, y, w = data(n)
        for name in ("exact", f"SoR m={args.inducing}"):
            if name == "exact" and n > args.exact_max:
                print(f"{n:6d} {name:>10} {'skipped':>8} {'':>9} {'(n > --exact-max)':>17}")
                continue
            box: dict = {}

            def fit(name: str = name, x: np.ndarray = x, y: np.ndarray = y,
                    w: np.ndarray = w, box: dict = box, n: int = n) -> None:
                if name == "exact":
                    box["m"] = fit_exact(x, y, w, hyper=hyper, keep_inverse=n <= 4000)
                else:
                    box["m"] = fit_sor(x, y, w, GpParams(inducing=args.inducing), hyper=hyper)

            dt, peak = measure(fit)
            rmse = float(np.sqrt(np.mean((box["m"].predict(xt)[0] - yt) ** 2)))
            print(f"{n:6d} {name:>10} {dt:8.2f} {peak:9.1f} {rmse:17.3f}")


if __name__ == "__main__":
    main()
