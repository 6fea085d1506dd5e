"""GP predictive variance k_i K^-1 k_i per row: `quadratic_rows` (one matrix product) against the
three-operand `np.einsum` it replaced, timed in the same run, with their largest relative
difference.

    python benchmarks/bench_gp_variance.py [--shapes 200x1000 2000x1500 50x3000] [--repeats 3]

Shapes are (prediction rows) x (training rows), the sizes of the cavitation stage's held-out
checks and exported models. One BLAS thread, as the test suite and a loaded rig PC run it.
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import time  # noqa: E402

import numpy as np  # noqa: E402

from rigtool.models.qctm import quadratic_rows  # noqa: E402


def best_of(fn, args: tuple, repeats: int) -> float:
    """Shortest wall time of `repeats` calls of fn(*args) (s)."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn(*args)
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--shapes", nargs="+", default=["200x1000", "2000x1500", "50x3000"])
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    print(f"{'shape':>10} {'einsum s':>9} {'matmul s':>9} {'ratio':>7} {'max rel diff':>13}")
    for shape in args.shapes:
        rows, n = (int(v) for v in shape.split("x"))
        k = rng.random((rows, n))
        a = rng.random((n, n))
        m = a @ a.T / n + np.eye(n)  # symmetric positive definite, like K^-1
        old = np.einsum("ij,jk,ik->i", k, m, k)
        new = quadratic_rows(k, m)
        t_old = best_of(np.einsum, ("ij,jk,ik->i", k, m, k), args.repeats)
        t_new = best_of(quadratic_rows, (k, m), args.repeats)
        diff = float(np.max(np.abs(new - old) / np.abs(old)))
        print(f"{shape:>10} {t_old:9.3f} {t_new:9.3f} {t_new / t_old:7.3f} {diff:13.1e}")


if __name__ == "__main__":
    main()
