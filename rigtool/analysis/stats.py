"""Serial correlation, stated once: the lag-1 autocorrelation of residuals or samples, the
AR(1) coefficient corrected for, and the effective sample size.

The rule, for every caller (fits.wls, the dynamics fits, the steady windows):

- r1 = sum of products of neighbours / sum of squares, over neighbours in the same segment
  (a held level, a point) only; 0 when the sum of squares is 0 (an exact fit). The steady
  windows sum every point at once (steady._window_stats) and pass the ratio: NaN for a
  constant channel there, whose batch-means error then decides.
- A negative r1 counts as 0: alternating errors would narrow an interval, and it is never
  narrowed for them.
- With `n` given, a positive r1 is first corrected for its small-sample bias, r1 + (1 + 3 r1) / n
  (the estimate is low by about that much); fits.wls, whose residuals sum to zero.
- r1 is capped at `max_r1`, which bounds n_eff from below at n (1 - max_r1) / (1 + max_r1):
  MAX_R1_FIT for fit residuals (tens to thousands of values, where an r1 nearer 1 is not
  told apart from a trend the model misses), MAX_R1_SAMPLES for the raw samples of a steady
  window (hundreds to thousands at 0.5-1 kHz, where 0.99 is what a slow sensor filter gives).
- Fit residuals (fits.wls) are first tested for serial correlation: a lag-1
  autocorrelation within what white residuals give one time in twenty (below
  -1/n + WHITE_Z / sqrt(n)) counts as none, so the interval is the regression's; only a
  significant r1 is corrected and used (`serially_correlated`).
- n_eff = n (1 - r1) / (1 + r1), at least the caller's floor (the parameters plus one for a
  criterion, 1 sample for a standard error).
"""

from __future__ import annotations

import numpy as np

MAX_R1_FIT = 0.98
MAX_R1_SAMPLES = 0.999
WHITE_Z = 1.645  # one-sided 95 % of the lag-1 autocorrelation of n white values


def serially_correlated(r1: float, n: int) -> bool:
    """Whether a raw lag-1 autocorrelation of n fit residuals is more than white residuals
    give one time in twenty (mean -1/n, standard deviation 1/sqrt(n))."""
    return n > 2 and r1 > -1.0 / n + WHITE_Z / np.sqrt(n)


def lag1_autocorrelation(r: np.ndarray, same: np.ndarray | None = None,
                         sum_squares: float | None = None) -> float:
    """Lag-1 autocorrelation of `r` (mean already removed); `same[i]`: r[i] and r[i + 1] are
    neighbours (None: all are). `sum_squares`: the caller's own sum of r^2 (the dynamics fits
    take it as a dot product, whose last bits differ from np.sum's). 0 when r is all zeros."""
    rss = float(np.sum(r * r)) if sum_squares is None else sum_squares
    products = r[1:] * r[:-1]
    if same is not None:
        products = products[same]
    return float(np.sum(products) / rss) if rss > 0 else 0.0


def ar1_coefficient(r1: float | np.ndarray, max_r1: float,
                    n: int | None = None) -> float | np.ndarray:
    """The correlation corrected for: r1 (or each of an array) by the module's rule."""
    if n is not None:
        r1 = np.where(r1 > 0, r1 + (1 + 3 * r1) / n, 0.0)
    out = np.clip(r1, 0.0, max_r1)
    return float(out) if np.ndim(out) == 0 else out


def effective_sample_size(n: float | np.ndarray, r1: float | np.ndarray,
                          floor: float = 0.0) -> float | np.ndarray:
    """n (1 - r1) / (1 + r1), at least `floor`: as many independent values as n AR(1) ones."""
    out = np.maximum(n * (1 - r1) / (1 + r1), floor)
    return float(out) if np.ndim(out) == 0 else out
