"""Measurement quality: hysteresis (up vs down), repeatability (across repeats), tare drift."""

from __future__ import annotations

import math

import numpy as np

from rigtool.analysis.fits import Coefficient
from rigtool.analysis.results import Hysteresis, Repeatability, TareDrift

SECONDS_PER_HOUR = 3600.0


def _group_mean(keys: np.ndarray, values: np.ndarray,
                se: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
    uniq, inv = np.unique(keys, return_inverse=True)
    k = np.bincount(inv, minlength=uniq.size)
    mean = np.bincount(inv, weights=values, minlength=uniq.size) / k
    out: tuple[np.ndarray, ...] = (uniq, inv, k, mean)
    if se is not None:
        out += (np.sqrt(np.bincount(inv, weights=np.nan_to_num(se) ** 2,
                                    minlength=uniq.size)) / k,)
    return out


def hysteresis(command: np.ndarray, direction: np.ndarray, mean: np.ndarray,
               se: np.ndarray) -> Hysteresis | None:
    """Per-command up minus down difference of the mean thrust; None without both sweeps."""
    ok = np.isfinite(mean)
    up = ok & (direction == "up")
    down = ok & (direction == "down")
    if not up.any() or not down.any():
        return None
    cu, _, _, mu, su = _group_mean(command[up], mean[up], se[up])
    cd, _, _, md, sd = _group_mean(command[down], mean[down], se[down])
    both, iu, idn = np.intersect1d(cu, cd, return_indices=True)
    if both.size == 0:
        return None
    return Hysteresis(both, mu[iu], md[idn], mu[iu] - md[idn], np.hypot(su[iu], sd[idn]))


def repeatability(command: np.ndarray, direction: np.ndarray, repeat: np.ndarray,
                  mean: np.ndarray) -> Repeatability | None:
    """Std (ddof 1) of point means across repeats at the same command and sweep direction."""
    ok = np.isfinite(mean)
    if np.unique(repeat[ok]).size < 2:
        return None
    dir_code = (direction[ok] == "down").astype(float)
    keys = np.column_stack([command[ok], dir_code])
    uniq, inv = np.unique(keys, axis=0, return_inverse=True)
    inv = inv.ravel()
    k = np.bincount(inv, minlength=len(uniq))
    m = np.bincount(inv, weights=mean[ok], minlength=len(uniq)) / k
    ss = np.bincount(inv, weights=(mean[ok] - m[inv]) ** 2, minlength=len(uniq))
    multi = k >= 2
    if not multi.any():
        return None
    return Repeatability(
        command=uniq[multi, 0],
        direction=np.where(uniq[multi, 1] > 0, "down", "up"),
        n_repeats=k[multi],
        std_n=np.sqrt(ss[multi] / (k[multi] - 1)),
    )


def drift_over_sweep(rate_n_per_h: float, interval: tuple[float, float], span_s: float,
                     noise_n: float, noise_ratio: float = 1.0) -> str | None:
    """How far a drift moves the zero over the sweep, when it matters: its 95 % interval
    excludes zero and that move exceeds `noise_ratio` times the thrust noise; else None."""
    lo, hi = interval
    if not (math.isfinite(lo) and math.isfinite(hi)) or lo <= 0.0 <= hi:
        return None
    moved_n = rate_n_per_h * span_s / SECONDS_PER_HOUR
    if not (math.isfinite(noise_n) and abs(moved_n) > noise_ratio * noise_n):
        return None
    return (f"{moved_n:+.2g} N over the sweep ({span_s / 60:.3g} min at {rate_n_per_h:.3g} N/h, "
            f"95 %: {lo:.3g} .. {hi:.3g} N/h), more than the thrust noise {noise_n:.2g} N")


def tare_drift(t_s: np.ndarray, bias_n: np.ndarray | None) -> TareDrift | None:
    """Linear trend (N/h, 95 % interval) of the thrust-channel tare bias; None under 2 tares."""
    from scipy import special

    if bias_n is None:
        return None
    ok = np.isfinite(t_s) & np.isfinite(bias_n)
    t, b = t_s[ok], bias_n[ok]
    n = t.size
    if n < 2 or np.ptp(t) <= 0:
        return None
    order = np.argsort(t, kind="stable")
    t, b = t[order], b[order] - b[order][0]
    hours = (t - t[0]) / SECONDS_PER_HOUR
    dx, dy = hours - hours.mean(), b - b.mean()
    sxx = float(dx @ dx)
    rate = float(dx @ dy) / sxx
    resid = dy - rate * dx
    lo = hi = math.nan
    r2 = math.nan
    if n > 2:
        hw = special.stdtrit(n - 2, 0.975) * math.sqrt(float(resid @ resid) / (n - 2) / sxx)
        lo, hi = rate - hw, rate + hw
        syy = float(dy @ dy)
        r2 = 1.0 - float(resid @ resid) / syy if syy > 0 else math.nan
    slope = Coefficient("tare_drift", rate, float(lo), float(hi), "N/h", n,
                        float(r2), float(np.sqrt(np.mean(resid**2))), "N",
                        "thrust-channel tare bias vs time, linear trend")
    scatter = float(np.sqrt(np.mean(np.diff(b) ** 2)))
    return TareDrift(t, b, slope, scatter)
