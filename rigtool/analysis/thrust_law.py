"""Which thrust-speed law a direction follows: f = C_p n^2, f = C_p n^2 + C_l n, or f = C n^k.

Real small thrusters depart from the textbook f = C_p |n| n (a linear term from the hub and
duct, exponents of 2.1-2.2). Each direction's points (thrust relative to the sensor zero
against |n|) are fitted with the three laws; the quadratic is kept unless another law
predicts held-out points better (interleaved K-fold) and its extra parameter differs from
the quadratic's value (C_l = 0, k = 2) by more than EXTRA_Z standard errors. The quadratic
is flagged inadequate where it misses the chosen law by more than ADEQUATE_FRAC of full-scale
thrust anywhere between LOW_FRAC and 100 % of the fastest point.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable

import numpy as np

from rigtool.models import laws

QUADRATIC, LINEAR, POWER = laws.THRUST_LAWS
FORMULAS = {QUADRATIC: "f = C_p n^2", LINEAR: "f = C_p n^2 + C_l n", POWER: "f = C n^k"}
FOLDS = 10
EXTRA_Z = 3.29  # the extra parameter must be this many SEs from its quadratic value (99.9 %)
ADEQUATE_FRAC = 0.02  # the quadratic may miss the chosen law by 2 % of full scale ...
LOW_FRAC = 0.1  # ... from 10 % of the fastest point's speed up
MIN_POINTS = 6  # fewer points: the quadratic, unjudged
K_BOUNDS = (1.0, 3.5)


def _weights(se: np.ndarray) -> np.ndarray:
    """1/se^2 where every point has a positive error, else equal weights."""
    if se.size and np.isfinite(se).all() and (se > 0).all():
        w = 1.0 / se**2
        return w / w.mean()
    return np.ones(se.size)


def _fit(family: str, x: np.ndarray, y: np.ndarray, w: np.ndarray
         ) -> tuple[dict[str, float], float]:
    """Parameters of `family` by weighted least squares, and the SE of its extra parameter
    (C_l or k; NaN for the quadratic or where it cannot be told)."""
    if family == QUADRATIC:
        return {"C_p": float(np.sum(w * y * x**2) / np.sum(w * x**4))}, math.nan
    if family == LINEAR:
        a = np.column_stack([x**2, x]) * np.sqrt(w)[:, None]
        beta, *_ = np.linalg.lstsq(a, y * np.sqrt(w), rcond=None)
        resid = y - np.column_stack([x**2, x]) @ beta
        dof = max(x.size - 2, 1)
        cov = np.linalg.pinv(a.T @ a) * float(np.sum(w * resid**2)) / dof
        return {"C_p": float(beta[0]), "C_l": float(beta[1])}, math.sqrt(max(cov[1, 1], 0.0))
    return _fit_power(x, y, w)


def _fit_power(x: np.ndarray, y: np.ndarray, w: np.ndarray) -> tuple[dict[str, float], float]:
    """f = C x^k: k by a bounded 1-D search with C in closed form; the SE of k from the
    curvature of the residual sum (Gauss-Newton)."""
    from scipy import optimize

    scale = float(np.max(x))
    u = x / scale

    def c_of(k: float) -> float:
        return float(np.sum(w * y * u**k) / np.sum(w * u ** (2 * k)))

    def cost(k: float) -> float:
        return float(np.sum(w * (y - c_of(k) * u**k) ** 2))

    k = float(optimize.minimize_scalar(cost, bounds=K_BOUNDS, method="bounded",
                                       options={"xatol": 1e-6}).x)
    c = c_of(k)
    with np.errstate(divide="ignore", invalid="ignore"):
        jac = np.column_stack([u**k, c * u**k * np.log(np.where(u > 0, u, 1.0))])
    a = jac * np.sqrt(w)[:, None]
    dof = max(x.size - 2, 1)
    cov = np.linalg.pinv(a.T @ a) * cost(k) / dof
    return {"C": c / scale**k, "k": k}, math.sqrt(max(cov[1, 1], 0.0))


def evaluate(family: str, params: dict[str, float], x: np.ndarray) -> np.ndarray:
    """Thrust magnitude at speed magnitude `x` (r/min) by `family` with `params`."""
    return laws.thrust_law(family, params, x)


def signed_law(laws_by_direction: dict[str, dict]) -> Callable[[np.ndarray], np.ndarray] | None:
    """Signed thrust (relative to the zero) at signed speed by each direction's chosen law
    (`choose_law` records, keyed "fwd"/"rev"); NaN on a side without a law. None without any."""
    if not laws_by_direction:
        return None

    def thrust(speed_rpm: np.ndarray) -> np.ndarray:
        n = np.asarray(speed_rpm, dtype=float)
        out = np.full(n.shape, np.nan)
        for key, sign in (("fwd", 1.0), ("rev", -1.0)):
            law = laws_by_direction.get(key)
            side = n * sign > 0
            if law is not None and side.any():
                out[side] = sign * evaluate(law["family"], law["params"], np.abs(n[side]))
        return out

    return thrust


def _held_out_rms(family: str, x: np.ndarray, y: np.ndarray, w: np.ndarray) -> float:
    """Weighted RMS of the prediction errors on interleaved held-out folds (by speed order)."""
    order = np.argsort(x, kind="stable")
    fold = np.empty(x.size, dtype=int)
    fold[order] = np.arange(x.size) % min(FOLDS, x.size)
    err = np.empty(x.size)
    for k in np.unique(fold):
        test = fold == k
        params, _ = _fit(family, x[~test], y[~test], w[~test])
        err[test] = y[test] - evaluate(family, params, x[test])
    return float(math.sqrt(np.sum(w * err**2) / np.sum(w)))


def _extra_z(family: str, fit: tuple[dict[str, float], float], x: np.ndarray, y: np.ndarray,
             w: np.ndarray, zero_sd_n: float) -> float:
    """How many standard errors the extra parameter (C_l, k) lies from its quadratic value (0,
    2), its error including what a shift of the zero by `zero_sd_n` moves it by."""
    name, null = ("C_l", 0.0) if family == LINEAR else ("k", 2.0)
    value, se = fit[0][name], fit[1]
    if zero_sd_n > 0:
        shifted = _fit(family, x, y + zero_sd_n, w)[0][name]
        se = math.hypot(se, shifted - value)
    return abs(value - null) / se if se > 0 else 0.0


def choose_law(speed_rpm: np.ndarray, thrust_n: np.ndarray, se_n: np.ndarray,
               zero_sd_n: float = 0.0) -> dict | None:
    """The law of one direction from its points (|n|, |f| relative to the zero, SE of f), as
    calibration.json records it; None with fewer than MIN_POINTS points. `zero_sd_n`: the
    standard error of the zero the thrusts are relative to: one shift shared by every point,
    which a linear term or an exponent would take up, so it adds to their errors."""
    x, y, se = (np.abs(np.asarray(v, dtype=float)) for v in (speed_rpm, thrust_n, se_n))
    ok = np.isfinite(x) & np.isfinite(y) & (x > 0)
    x, y, se = x[ok], y[ok], se[ok]
    if x.size < MIN_POINTS:
        return None
    w = _weights(se)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        fits = {f: _fit(f, x, y, w) for f in (QUADRATIC, LINEAR, POWER)}
        cv = {f: _held_out_rms(f, x, y, w) for f in fits}
        z = {f: _extra_z(f, fits[f], x, y, w, zero_sd_n) for f in (LINEAR, POWER)}
    better = [f for f in (LINEAR, POWER) if z[f] > EXTRA_Z and cv[f] < cv[QUADRATIC]]
    family = min(better, key=lambda f: cv[f]) if better else QUADRATIC
    top = float(x.max())
    grid = np.linspace(LOW_FRAC * top, top, 200)
    chosen = evaluate(family, fits[family][0], grid)
    quad = evaluate(QUADRATIC, fits[QUADRATIC][0], grid)
    full = float(abs(evaluate(family, fits[family][0], np.array([top]))[0]))
    miss = float(np.max(np.abs(chosen - quad)) / full) if full > 0 else math.nan
    return {
        "family": family,
        "formula": FORMULAS[family],
        "params": fits[family][0],
        "quadratic_c_p": fits[QUADRATIC][0]["C_p"],
        "held_out_rms_n": cv,
        "extra_parameter_z": z,
        "speed_range_rpm": [float(x.min()), top],
        "full_scale_n": full,
        "quadratic_max_miss_frac": miss,
        "quadratic_adequate": bool(not miss > ADEQUATE_FRAC),
        "n_points": int(x.size),
    }
