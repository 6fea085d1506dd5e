"""QCTM-GP: weighted Matern-5/2 GP on standardised (n, z, h), exact and sparse (SoR) forms
([Rasmussen2006], docs/references.md).

Inputs are `rigtool.models.gp_features`: z is the current-implied thrust loss. `fit_hetero`
adds a heteroscedastic noise model (a second GP on the log of local 95 % quantiles of the
squared residuals, quiet and ventilating rows apart, see `fit_noise`); the exact GP then uses
alpha_i = var(x_i) / w_i and its intervals add var(x). `calibrate_gate` scales that noise
model on held-out residuals (the folds are the caller's: rigtool.analysis.cavitation).

Hyperparameters (ARD length scales, signal variance, noise variance sigma^2) are fitted by
maximum likelihood with a WhiteKernel on a subset of at most `hyper_n` points (cubic cost);
the final exact GP then uses all points with fixed hyperparameters and per-sample noise
alpha_i = sigma^2 / w_i. scikit-learn's normalize_y=True works in units of y's standard
deviation, so alpha is divided by var(y); predict(return_std=True) leaves the noise out, so
intervals for a new measurement add sigma^2 back. The sparse alternative is a
subset-of-regressors GP with m inducing points and the same hyperparameters (cost n m^2).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass
from statistics import NormalDist
from typing import TYPE_CHECKING

import numpy as np

from rigtool.models.qctm import Z95, GatedMean, LogNoise, gate, matern52, quadratic_rows

if TYPE_CHECKING:
    from sklearn.gaussian_process import GaussianProcessRegressor

NU = 2.5
MIN_GATE_GAIN = 0.01  # the gate must cut the weighted squared residual by this fraction
# Smoothness prior: no length scale below one standard deviation of its (standardised) input.
# Shorter ones let the GP give each command level or event its own offset, which does not
# carry over to another run (docs/cavitation.md, 'Measured figures').
MIN_LENGTH_SCALE = 1.0
# The noise GP's smoothness prior: the jump between quiet and ventilating blocks is the
# gate's (`calibrate_gate`), the GP only needs slow trends; short length scales (0.2 sd in z)
# made models fitted on part of the points extrapolate to the others by a factor of 10 in sd.
MIN_NOISE_LENGTH_SCALE = 1.0
NOISE_SMOOTHING = 1.0  # length scale (standardised inputs) of `local_square_quantile`
# Bounds of the noise GP (log variance): its targets vary by ~1 (variance 0.5-1.5). Without
# them the likelihood went to a signal variance of 1000 and a white noise of 1e-3 (the old
# bounds), the GP interpolated its rough targets exactly and swung to -10 (a factor exp(-10)
# on the variance) between rows; a fold model's held-out events fell into such a hole and
# the interval check widened the exported intervals to +-68 N (research/cavitation-log.md).
MAX_NOISE_SIGNAL_VAR = 4.0
MIN_NOISE_WHITE_VAR = 0.05
MIN_SIDE_ROWS = 20  # rows a side (quiet, ventilating) needs for a noise level of its own
CV_TOLERANCE = 0.02  # a GP signal must cut the held-out error by more than 2 % to be kept
# candidate factors on the ML signal variance for cross-validation; 0 is the mean term alone
SIGNAL_SCALES = (1.0, 0.3, 0.1, 0.03, 0.01, 0.0)
# the default: the mean term alone. Cross-validation over two training runs chose a GP signal
# that failed on new runs (held-out event p95 up to 9.9 N against 2.2-3.6 N), see
# docs/cavitation.md; GpParams(signal_scales=SIGNAL_SCALES) lets it choose anyway.
MEAN_TERM_ONLY = (0.0,)


@dataclass(frozen=True)
class GpParams:
    """GP fitting options (recorded with the results)."""

    hyper_n: int = 500  # points used for each hyperparameter search (mean and noise GPs)
    n_restarts: int = 1
    seed: int = 0
    inducing: int = 300  # inducing points of the sparse (SoR) variant
    signal_scales: tuple[float, ...] = MEAN_TERM_ONLY  # candidates for `cv_signal_scale`


@dataclass
class Hyper:
    """Kernel hyperparameters in standardised units (inputs) and normalised units (y)."""

    length_scales: np.ndarray
    signal_var: float  # of normalised y
    noise_var: float  # of normalised y, at weight 1


class Standardiser:
    """x -> (x - mean) / scale, per column."""

    def __init__(self, x: np.ndarray) -> None:
        self.mean = x.mean(axis=0)
        self.scale = np.where(x.std(axis=0) > 0, x.std(axis=0), 1.0)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return (np.asarray(x, dtype=float) - self.mean) / self.scale


def fit_hyper(xs: np.ndarray, yn: np.ndarray, w: np.ndarray, p: GpParams) -> Hyper:
    """ML hyperparameters on a subset (prefers well-weighted points), standardised inputs."""
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel

    rng = np.random.default_rng(p.seed)
    good = np.flatnonzero(w >= 0.5)
    pool = good if good.size >= min(p.hyper_n, 50) else np.arange(yn.size)
    sub = pool if pool.size <= p.hyper_n else np.sort(rng.choice(pool, p.hyper_n, replace=False))
    kernel = (ConstantKernel(1.0, (1e-3, 1e3))
              * Matern(length_scale=np.ones(xs.shape[1]),
                     length_scale_bounds=(MIN_LENGTH_SCALE, 1e3), nu=NU)
              + WhiteKernel(0.05, (1e-6, 1.0)))
    gpr = GaussianProcessRegressor(kernel, normalize_y=False, n_restarts_optimizer=p.n_restarts,
                                   random_state=p.seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        gpr.fit(xs[sub], yn[sub])
    k = gpr.kernel_
    return Hyper(np.atleast_1d(k.k1.k2.length_scale).astype(float), float(k.k1.k1.constant_value),
                 float(k.k2.noise_level))


@dataclass
class ExactGp:
    """Fitted exact GP: everything needed to evaluate the posterior without scikit-learn."""

    x_mean: np.ndarray
    x_scale: np.ndarray
    y_mean: float
    y_std: float
    hyper: Hyper
    x_train: np.ndarray  # raw inputs (n, 3)
    w: np.ndarray
    alpha: np.ndarray  # (K + diag(noise / w))^-1 yn, normalised units
    k_inv: np.ndarray | None  # (K + diag)^-1, for the posterior variance
    sklearn: GaussianProcessRegressor | None = None
    noise: LogNoise | None = None  # heteroscedastic noise model (None: constant noise_var)
    mean_term: GatedMean = GatedMean()  # explicit mean g(x[:, 1]) (z, the shortfall thrust)
    signal_scale: float = 1.0  # factor cross-validation put on the ML signal variance
    check: dict | None = None  # held-out interval check and floor (rigtool.analysis.cavitation)

    @property
    def noise_var_n2(self) -> float:
        """Constant sigma^2 of a new measurement at weight 1 (N^2; 0 with a noise model)."""
        return self.hyper.noise_var * self.y_std**2

    def noise_n2(self, x: np.ndarray) -> np.ndarray:
        """Noise variance of a new measurement at inputs x (N^2)."""
        if self.noise is None:
            return np.full(len(x), self.noise_var_n2)
        return self.noise.var_n2(x)

    def predict(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(mean, std of a new measurement) in N, numpy only."""
        xs_raw = np.asarray(x, dtype=float)
        xs = (xs_raw - self.x_mean) / self.x_scale
        xt = (self.x_train - self.x_mean) / self.x_scale
        k = self.hyper.signal_var * matern52(xs, xt, self.hyper.length_scales)
        mean = self.y_mean + self.mean_term(xs_raw[:, 1]) + self.y_std * (k @ self.alpha)
        var_n = np.full(len(xs), self.hyper.signal_var)
        if self.k_inv is not None:
            var_n = var_n - quadratic_rows(k, self.k_inv)
        var = self.y_std**2 * np.maximum(var_n, 0.0) + self.noise_n2(x)
        return mean, np.sqrt(var)


def fit_hyper_fixed_noise(xs: np.ndarray, yn: np.ndarray, alpha: np.ndarray,
                          p: GpParams) -> Hyper:
    """ML length scales and signal variance with given per-row noise (normalised units)."""
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import ConstantKernel, Matern

    rng = np.random.default_rng(p.seed)
    sub = (np.arange(yn.size) if yn.size <= p.hyper_n
           else np.sort(rng.choice(yn.size, p.hyper_n, replace=False)))
    kernel = (ConstantKernel(1.0, (1e-3, 1e3))
              * Matern(length_scale=np.ones(xs.shape[1]),
                     length_scale_bounds=(MIN_LENGTH_SCALE, 1e3), nu=NU))
    gpr = GaussianProcessRegressor(kernel, alpha=alpha[sub], normalize_y=False,
                                   n_restarts_optimizer=p.n_restarts, random_state=p.seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        gpr.fit(xs[sub], yn[sub])
    k = gpr.kernel_
    return Hyper(np.atleast_1d(k.k2.length_scale).astype(float), float(k.k1.constant_value), 0.0)


def fit_noise(x: np.ndarray, resid: np.ndarray, p: GpParams, kernel: LogNoise | None = None,
              mean_term: GatedMean | None = None) -> LogNoise:
    """Noise model: log var(x) = log_mean + bias(z) + GP(x), fitted at <= hyper_n rows on the
    log of the local 95 % quantile of resid^2 (`local_square_quantile`). With `mean_term`, its gate
    splits the rows into quiet (gate < 1/2) and ventilating ones: each side is smoothed on its
    own, and a level for each (bias(z) = log_bias + (log_bias_event - log_bias) gate(z)) is
    fitted before the GP (Matern 5/2 + white, every length scale at least
    MIN_NOISE_LENGTH_SCALE) models what the levels leave. Each level is then set so that 95 %
    of its side's rows have |resid| <= 1.96 sqrt(var(x)); the held-out check
    (`calibrate_gate`) scales them. `kernel`: a fitted model whose kernel hyperparameters are
    reused (no ML search)."""
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.gaussian_process import GaussianProcessRegressor

    st = Standardiser(x)
    rng = np.random.default_rng(p.seed + 1)
    sub = (np.arange(resid.size) if resid.size <= p.hyper_n
           else np.sort(rng.choice(resid.size, p.hyper_n, replace=False)))
    g = _mean_gate(x, mean_term)
    floor = max(1e-6, 1e-4 * float(np.median(resid**2)))
    ly = np.log(local_square_quantile(st(x), resid, g >= 0.5, sub) + floor)
    levels = _gate_levels(ly, g[sub])
    fixed = kernel is not None and kernel.white_var is not None
    gpr = GaussianProcessRegressor(_noise_kernel(x.shape[1], kernel if fixed else None),
                                   normalize_y=False, n_restarts_optimizer=p.n_restarts,
                                   random_state=p.seed,
                                   optimizer=None if fixed else "fmin_l_bfgs_b")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        gpr.fit(st(x[sub]), ly - levels[0] - (levels[1] - levels[0]) * g[sub])
    k = gpr.kernel_
    noise = LogNoise(st.mean, st.scale, np.atleast_1d(k.k1.k2.length_scale).astype(float),
                     float(k.k1.k1.constant_value), levels[0], np.asarray(x[sub], float),
                     np.ravel(gpr.alpha_), 0.0, white_var=float(k.k2.noise_level))
    if mean_term is not None and mean_term.s > 0:
        noise.gate_z0, noise.gate_s = mean_term.z0, mean_term.s
        noise.log_bias_event = levels[1] - levels[0]
    return _side_biases(noise, x, resid, g >= 0.5)


def local_square_quantile(xs: np.ndarray, resid: np.ndarray, side: np.ndarray,
                          at: np.ndarray, q: float = 0.95) -> np.ndarray:
    """Kernel-weighted q-quantile of resid^2 over the rows on the same side (quiet or
    ventilating) as each row of `at` (standardised inputs, Matern 5/2 of length
    NOISE_SMOOTHING), divided by Z95^2: the variance whose 1.96-sd interval covers q of the
    neighbourhood. Where quiet blocks mix with ventilating ones the shortfall cannot tell
    from them, that quantile is set by the latter, as a 95 % interval must be; a mean of
    log resid^2 (a geometric mean) puts it far too low. The sides are kept apart: a
    ventilating block's error is 10-100 times a quiet one's."""
    r2 = np.asarray(resid, float) ** 2
    order = np.argsort(r2)
    k = matern52(xs[at], xs[order], np.full(xs.shape[1], NOISE_SMOOTHING))
    k = np.where(side[at][:, None] == side[order][None, :], k, 0.0)
    cum = np.cumsum(k, axis=1)
    idx = np.sum(cum < q * cum[:, -1:], axis=1)
    return r2[order][np.minimum(idx, r2.size - 1)] / Z95**2


def _mean_gate(x: np.ndarray, mean_term: GatedMean | None) -> np.ndarray:
    """The mean term's gate at every row (0 without a mean term or gate)."""
    if mean_term is None:
        return np.zeros(len(x))
    return gate(np.asarray(x, float)[:, 1], mean_term.z0, mean_term.s)


def _gate_levels(ly: np.ndarray, g: np.ndarray) -> tuple[float, float]:
    """Least-squares levels (quiet, ventilating) of ly = a (1 - g) + b g; both the mean of ly
    when one side has too few rows to tell."""
    if min(float(np.sum(g)), float(np.sum(1.0 - g))) < MIN_SIDE_ROWS:
        return float(np.mean(ly)), float(np.mean(ly))
    a, b = np.linalg.lstsq(np.column_stack([1.0 - g, g]), ly, rcond=None)[0]
    return float(a), float(b)


def _side_biases(noise: LogNoise, x: np.ndarray, resid: np.ndarray,
                 hi: np.ndarray) -> LogNoise:
    """`noise` with biases raised so that 95 % of each side's rows (`hi`: ventilating) are
    covered; one bias when a side has too few rows or the model has no gate."""
    ratio = resid**2 / noise.var_n2(x)
    out = LogNoise(**{**noise.__dict__})

    def level(rows: np.ndarray) -> float:
        rows = rows if rows.sum() >= MIN_SIDE_ROWS else np.ones(rows.size, bool)
        return float(np.log(np.quantile(ratio[rows], 0.95) / Z95**2))

    if noise.log_bias_event is None:
        out.log_bias = noise.log_bias + level(np.ones(hi.size, bool))
        return out
    out.log_bias = noise.log_bias + level(~hi)
    out.log_bias_event = noise.log_bias_event + level(hi)
    return out


def _noise_kernel(dim: int, fitted: LogNoise | None):  # noqa: ANN202 (a scikit-learn kernel)
    """Matern 5/2 + white kernel of the noise GP: to be fitted, or `fitted`'s, held fixed."""
    from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel

    if fitted is None or fitted.white_var is None:
        return (ConstantKernel(1.0, (1e-3, MAX_NOISE_SIGNAL_VAR))
                * Matern(length_scale=np.ones(dim),
                         length_scale_bounds=(MIN_NOISE_LENGTH_SCALE, 1e3), nu=NU)
                + WhiteKernel(1.0, (MIN_NOISE_WHITE_VAR, 10.0)))
    return (ConstantKernel(fitted.signal_var, "fixed")
            * Matern(length_scale=fitted.length_scales, length_scale_bounds="fixed", nu=NU)
            + WhiteKernel(fitted.white_var, "fixed"))


def fit_hetero(x: np.ndarray, y: np.ndarray, w: np.ndarray, fold: np.ndarray,
               params: GpParams | None = None, groups: np.ndarray | None = None,
               reuse: ExactGp | None = None) -> ExactGp:
    """Exact GP with heteroscedastic noise on top of the gated mean term g(z)
    (`fit_gated_mean`; z = x[:, 1], the current-implied thrust loss), which is taken out of y
    first: the GP only corrects it.

    By default (every candidate of `params.signal_scales` is 0) the GP has no signal: the
    model is g(z) + a constant, and its noise model (`fit_noise`) is fitted on that
    predictor's own residuals (`_fit_without_signal`). Otherwise `_fit_with_signal`: a GP
    signal chosen by cross-validation over `fold` (0/1 per row; hold out whole points or
    runs: blocks of one point, or of one ventilation event, are autocorrelated and leak).
    `reuse`: a fit whose kernel hyperparameters and gate (z0, s) are reused instead of
    searched for (the refits of `crossfit`: `refit_beta`); then no posterior-variance matrix
    is kept."""
    p = params or GpParams()
    fold = np.asarray(fold)
    if fold.shape != (len(y),) or not set(np.unique(fold).tolist()) <= {0, 1}:
        raise ValueError("fit_hetero: fold must give 0 or 1 for every row")
    mean_term = (fit_gated_mean(x[:, 1], y, w) if reuse is None
                 else refit_beta(x[:, 1], y, w, reuse.mean_term))
    y = y - mean_term(x[:, 1])  # the GP models what the mean term leaves
    if max(p.signal_scales) > 0:
        gp = _fit_with_signal(x, y, w, fold, p, groups, mean_term, reuse)
    else:
        gp = _fit_without_signal(x, y, w, p, mean_term, reuse)
    gp.mean_term = mean_term
    return gp


def _fit_without_signal(x: np.ndarray, y: np.ndarray, w: np.ndarray, p: GpParams,
                        mean_term: GatedMean, reuse: ExactGp | None) -> ExactGp:
    """y (mean term already out) as a constant plus noise var(x) fitted on y - mean(y)."""
    noise = fit_noise(x, y - np.mean(y), p, None if reuse is None else reuse.noise,
                      mean_term)
    hyper = Hyper(np.full(x.shape[1], MIN_LENGTH_SCALE), 0.0, 0.0)
    gp = fit_exact(x, y, w, p, hyper=hyper, noise=noise, keep_inverse=reuse is None)
    gp.signal_scale = 0.0
    return gp


def _fit_with_signal(x: np.ndarray, y: np.ndarray, w: np.ndarray, fold: np.ndarray,
                     p: GpParams, groups: np.ndarray | None, mean_term: GatedMean,
                     reuse: ExactGp | None) -> ExactGp:
    """(1) homoscedastic hyperparameters, (2) residuals of a 2-fold cross-fit, (3) noise
    model on their logs, (4) length scales and signal variance again with the noise fixed,
    (5) the signal variance scaled down by cross-validation over the same folds
    (`cv_signal_scale`: maximum likelihood reads the autocorrelated rows of one event as
    signal; `groups`, a label per point, sets the error's standard error), (6) final exact
    GP with alpha_i = var(x_i) / w_i. With `reuse`, its hyperparameters (signal already
    scaled) replace steps 1, 4 and 5."""
    h0 = reuse.hyper if reuse is not None else fit_exact(x, y, w, p, keep_inverse=False).hyper
    n0 = None if reuse is None else reuse.noise  # its hyper has no white noise of its own
    resid = np.empty_like(np.asarray(y, float))
    if np.unique(fold).size < 2:
        resid = y - fit_exact(x, y, w, p, hyper=h0, keep_inverse=False, noise=n0).predict(x)[0]
    else:
        for k in (0, 1):
            a = fold != k
            g = fit_exact(x[a], y[a], w[a], p, hyper=h0, keep_inverse=False, noise=n0)
            resid[~a] = y[~a] - g.predict(x[~a])[0]
    noise = fit_noise(x, resid, p, None if reuse is None else reuse.noise, mean_term)
    if reuse is not None:
        h1, scale = reuse.hyper, reuse.signal_scale
    else:
        st = Standardiser(x)
        y_std = float(np.std(y)) or 1.0
        alpha = noise.var_n2(x) / w / y_std**2
        h1 = fit_hyper_fixed_noise(st(x), (y - np.mean(y)) / y_std, alpha, p)
        scale = cv_signal_scale(x, y, w, fold, h1, noise, p, groups)
        h1 = Hyper(h1.length_scales, scale * h1.signal_var, h1.noise_var)
    gp = fit_exact(x, y, w, p, hyper=h1, noise=noise, keep_inverse=reuse is None)
    gp.signal_scale = scale
    return gp


def cv_signal_scale(x: np.ndarray, y: np.ndarray, w: np.ndarray, fold: np.ndarray,
                    hyper: Hyper, noise: LogNoise, p: GpParams,
                    groups: np.ndarray | None = None) -> float:
    """The smallest factor in `p.signal_scales` on the signal variance whose weighted squared
    error on held-out folds is within one standard error, or CV_TOLERANCE, of the best
    factor's (the only candidate if there is one; the largest when there is only one fold). The standard error of the difference comes
    from per-point sums (`groups`; else per fold). Taking the simplest model within the
    noise of the criterion keeps near-identical inputs from flipping between the two
    likelihood optima; factor 0 is the mean term alone."""
    scales = p.signal_scales
    if len(scales) == 1:
        return scales[0]
    if np.unique(fold).size < 2:
        return max(scales)
    labels = np.asarray(fold if groups is None else groups)
    _, g_idx = np.unique(labels, return_inverse=True)
    per_group = []
    for c in scales:
        h = Hyper(hyper.length_scales, c * hyper.signal_var, hyper.noise_var)
        err = np.zeros(len(y))
        for k in (0, 1):
            a = fold != k
            g = fit_exact(x[a], y[a], w[a], p, hyper=h, noise=noise, keep_inverse=False)
            err[~a] = w[~a] * (y[~a] - g.predict(x[~a])[0]) ** 2
        per_group.append(np.bincount(g_idx, weights=err))
    sums = np.array(per_group)  # (factors, groups)
    best = int(np.argmin(sums.sum(axis=1)))
    tolerance = CV_TOLERANCE * float(sums[best].sum())
    for j in sorted(range(len(scales)), key=lambda j: scales[j]):
        d = sums[j] - sums[best]
        se = float(np.sqrt(d.size) * np.std(d, ddof=1)) if d.size > 1 else 0.0
        if d.sum() <= max(se, tolerance):
            return scales[j]
    return scales[best]


def variance_parts(gp: ExactGp, x: np.ndarray) -> np.ndarray:
    """Rows mean (N), posterior variance and noise variance (N^2) of a new measurement at x."""
    mean, std = gp.predict(x)
    noise = gp.noise_n2(x)
    return np.vstack([mean, np.maximum(std**2 - noise, 0.0), noise])


SHIFT_RANGE = 6.0  # log-variance shifts are searched in +-this (a factor exp(+-3) on the sd)
MIN_CHECK_ROWS = 30  # held-out rows of a class below which it gets no shift of its own
EVENT_EXTRA = 1.0  # log-variance the detected events may add to cover ventilation the gate misses
# log-variance the check may take off the event intervals (a factor 0.55 on the sd): with the
# missed ventilation covered apart, a check over 12-17 held-out events asked for up to -1.8
# (sd x 0.4) and a new run's events were covered 85 % (cal-dev replay, research/cavitation-log.md)
EVENT_SHRINK = 1.2
MIN_MISSED_ROWS = 5  # held-out missed-ventilation rows a speed level needs for a widening
MISSED_OWN_ROWS = 45  # missed rows from which their 95 % bound is no longer their largest
MISSED_CONFIDENCE = 0.9  # confidence of the upper bound on the missed rows' quantile


@dataclass(frozen=True)
class GateShift:
    """A held-out scale of the noise: row noise var times exp((1 - g) d_quiet + g d_event),
    g = gate(z, z0, s) (the noise model's gate)."""

    z0: float
    s: float
    d_quiet: float
    d_event: float
    # the loss-side widening (N) for ventilation the gate misses, per speed knot (r/min)
    missed_speed_rpm: tuple[float, ...] | None = None
    missed_lower_n: tuple[float, ...] | None = None

    def factor(self, z: np.ndarray) -> np.ndarray:
        """The factor on the noise variance at shortfall thrust z."""
        g = gate(z, self.z0, self.s)
        return np.exp((1.0 - g) * self.d_quiet + g * self.d_event)

    def missed(self, speed_rpm: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Loss-side widening (N): (1 - gate(z)) times the table at |speed| (0 without one)."""
        if self.missed_speed_rpm is None or self.missed_lower_n is None:
            return np.zeros(np.shape(z))
        table = np.interp(np.abs(speed_rpm), self.missed_speed_rpm, self.missed_lower_n)
        return (1.0 - gate(z, self.z0, self.s)) * table


def calibrate_gate(resid: np.ndarray, post_var: np.ndarray, noise_var: np.ndarray,
                   z: np.ndarray, event: np.ndarray, outside: np.ndarray,
                   z0: float, s: float, level: float = 0.95,
                   outside_level: float | None = None, speed_rpm: np.ndarray | None = None,
                   speed_level: np.ndarray | None = None,
                   loss_cap_n: np.ndarray | None = None) -> GateShift:
    """The scale under which held-out residuals are covered at `level` during events and at
    `outside_level` (default `level`) outside them: `class_shifts` on the `outside` and the
    `event` rows, the latter through the rows the gate (z0, s) calls ventilating. Without
    enough rows of a class, one shift for all at `level`; without enough held-out rows at
    all, none. With `speed_rpm` and `speed_level` (a label per row, e.g. the command), the
    event rows the gate calls quiet are covered by a loss-side widening per speed level
    (`missed_widening`; `loss_cap_n`: the loss ventilation can cause at each row, for speed
    levels that saw too little missed ventilation) instead of by wider event intervals."""
    if speed_rpm is not None and speed_level is not None and min(
            event.sum(), outside.sum()) >= MIN_CHECK_ROWS:
        return _calibrate_with_missed(np.asarray(resid, float), post_var, noise_var, z, event,
                                      outside, z0, s, level, outside_level,
                                      np.asarray(speed_rpm, float), np.asarray(speed_level),
                                      loss_cap_n)
    r2 = np.asarray(resid, float) ** 2 / Z95**2
    if event.sum() < MIN_CHECK_ROWS or outside.sum() < MIN_CHECK_ROWS:
        use = event | outside
        rows = use if use.sum() >= MIN_CHECK_ROWS else np.isfinite(r2)
        if rows.sum() < MIN_CHECK_ROWS:
            return GateShift(z0, s, 0.0, 0.0)  # nothing to check on: the fit's own scale
        d = _bisect_shift(lambda c: _coverage(r2, post_var, noise_var, rows, c), level)
        return GateShift(z0, s, d, d)
    dq, de = class_shifts(r2, post_var, noise_var, gate(z, z0, s), outside, event, level,
                          outside_level=outside_level)
    return GateShift(z0, s, dq, de)


def class_shifts(r2: np.ndarray, post_var: np.ndarray, noise_var: np.ndarray, g: np.ndarray,
                 outside: np.ndarray, event: np.ndarray, level: float,
                 rounds: int = 4, outside_level: float | None = None) -> tuple[float, float]:
    """(d_quiet, d_event), in turn: d_quiet covers `outside_level` (default `level`) of the
    `outside` rows; d_event covers `level` of the `event` rows the gate calls ventilating
    (g >= 1/2), then more, up to EVENT_EXTRA, until the `event` rows as a whole are covered
    at `level`: ventilation the shortfall misses gets the quiet intervals, and the detected
    events make up for it (d_event = d_quiet when too few rows are gated)."""
    dq = de = 0.0
    hi = event & (g >= 0.5)
    quiet_level = level if outside_level is None else outside_level

    def cover(rows: np.ndarray, a: float, b: float) -> float:
        var = post_var + noise_var * np.exp((1 - g) * a + g * b)
        return float(np.mean(r2[rows] <= var[rows]))

    for _ in range(rounds):
        dq = _bisect_shift(lambda c, b=de: cover(outside, c, b), quiet_level)
        if hi.sum() < MIN_CHECK_ROWS:
            de = dq
            continue
        de = _bisect_shift(lambda c, a=dq: cover(hi, a, c), level)
        more = _bisect_shift(lambda c, a=dq: cover(event, a, c), level)
        de = min(de + EVENT_EXTRA, max(de, more))
    return dq, de


def _calibrate_with_missed(resid: np.ndarray, post_var: np.ndarray, noise_var: np.ndarray,
                           z: np.ndarray, event: np.ndarray, outside: np.ndarray, z0: float,
                           s: float, level: float, outside_level: float | None,
                           speed_rpm: np.ndarray, speed_level: np.ndarray,
                           loss_cap_n: np.ndarray | None = None, rounds: int = 4) -> GateShift:
    """`calibrate_gate` with the loss-side widening, in turn: d_quiet covers `outside_level` of
    the outside rows; d_event covers `level` of the event rows the gate calls ventilating;
    the widening per speed level covers `level` of the event rows it calls quiet (ventilation
    the shortfall misses: only a thrust loss, so only the loss side); then d_event grows, by
    at most EVENT_EXTRA, until `level` of all event rows are covered. d_event is at least
    -EVENT_SHRINK."""
    g = gate(z, z0, s)
    u = resid * np.where(np.sign(speed_rpm) >= 0, 1.0, -1.0)  # < 0: a thrust loss
    quiet_level = level if outside_level is None else outside_level
    gated, missed = event & (g >= 0.5), event & (g < 0.5)
    knots, levels = _speed_knots(speed_rpm, speed_level)
    table = np.zeros(knots.size)
    dq = de = 0.0

    def half(a: float, b: float) -> np.ndarray:
        return Z95 * np.sqrt(post_var + noise_var * np.exp((1 - g) * a + g * b))

    def cover(rows: np.ndarray, a: float, b: float) -> float:
        h = half(a, b)
        extra = (1.0 - g) * np.interp(np.abs(speed_rpm), knots, table)
        return float(np.mean((u[rows] <= h[rows]) & (-u[rows] <= h[rows] + extra[rows])))

    for _ in range(rounds):
        dq = _bisect_shift(lambda c, b=de: cover(outside, c, b), quiet_level)
        if gated.sum() < MIN_CHECK_ROWS:
            de = dq
        else:
            de = _bisect_shift(lambda c, a=dq: cover(gated, a, c), level)
        table = missed_widening(u, half(dq, de), g, missed, speed_level, levels, level,
                                event, loss_cap_n)
        if gated.sum() >= MIN_CHECK_ROWS:
            more = _bisect_shift(lambda c, a=dq: cover(event, a, c), level)
            de = min(de + EVENT_EXTRA, max(de, more))
    de = max(de, -EVENT_SHRINK)
    return GateShift(z0, s, dq, de, tuple(float(k) for k in knots),
                     tuple(float(v) for v in table))


def _speed_knots(speed_rpm: np.ndarray, speed_level: np.ndarray) -> tuple[np.ndarray, list]:
    """Strictly increasing knots, the median |speed| of each level's rows, and the levels of
    each knot (levels of one median share a knot)."""
    by_speed: dict[float, list] = {}
    for lv in np.unique(speed_level):
        sp = np.abs(speed_rpm[(speed_level == lv) & np.isfinite(speed_rpm)])
        if sp.size:
            by_speed.setdefault(float(np.median(sp)), []).append(lv)
    knots = np.array(sorted(by_speed), float)
    return (knots if knots.size else np.zeros(1)), [by_speed[k] for k in sorted(by_speed)]


def missed_widening(u: np.ndarray, half: np.ndarray, g: np.ndarray, missed: np.ndarray,
                    speed_level: np.ndarray, levels: list, level: float,
                    event: np.ndarray | None = None,
                    loss_cap_n: np.ndarray | None = None) -> np.ndarray:
    """Per speed knot (`levels`: the speed levels of each knot, from `_speed_knots`), the
    loss-side widening (N, before the factor 1 - gate) that covers `level` of that knot's
    missed-ventilation rows (`missed`: event rows the gate calls quiet) beyond their
    half-width `half`, as a small-sample upper bound (`upper_quantile`). Where those rows
    are too few to tell (under MISSED_OWN_ROWS) and the gate misses most of the knot's
    `event` rows or saw under MIN_CHECK_ROWS of them, at least the loss ventilation can
    cause there (`loss_cap_n` per row) beyond the half-width, median over the knot's rows."""
    need = np.maximum(-u - half, 0.0) / np.maximum(1.0 - g, 0.5)
    ok = missed & np.isfinite(need)
    out = np.zeros(max(len(levels), 1))
    for j, lvs in enumerate(levels):
        at = np.isin(speed_level, lvs)
        rows = ok & at
        n_missed = int(rows.sum())
        if n_missed >= MIN_MISSED_ROWS:
            out[j] = upper_quantile(need[rows], level)
        if n_missed >= MISSED_OWN_ROWS or event is None or loss_cap_n is None:
            continue
        n_event = int((event & at).sum())
        if n_event < MIN_CHECK_ROWS or 2 * n_missed >= n_event:
            cap = np.maximum(loss_cap_n - half, 0.0)[at & np.isfinite(loss_cap_n)]
            if cap.size:
                out[j] = max(out[j], float(np.median(cap)))
    return out


def upper_quantile(x: np.ndarray, level: float, confidence: float = MISSED_CONFIDENCE) -> float:
    """A distribution-free upper bound on the `level` quantile of x's population: the order
    statistic at rank level (n + 1) + z_conf sqrt(n level (1 - level)) (normal approximation
    of the binomial), the largest value when the rows are too few for that rank."""
    v = np.sort(np.asarray(x, float))
    n = v.size
    z = NormalDist().inv_cdf(confidence)
    rank = int(np.ceil(level * (n + 1) + z * np.sqrt(n * level * (1.0 - level))))
    return float(v[min(max(rank, 1), n) - 1])


def _coverage(r2: np.ndarray, post_var: np.ndarray, noise_var: np.ndarray, rows: np.ndarray,
              shift: float) -> float:
    """Fraction of `rows` covered with the noise variance times exp(shift)."""
    return float(np.mean(r2[rows] <= post_var[rows] + noise_var[rows] * np.exp(shift)))


def _bisect_shift(coverage: Callable[[float], float], level: float) -> float:
    """Smallest shift in +-SHIFT_RANGE whose coverage reaches `level` (coverage rises with it)."""
    lo, hi = -SHIFT_RANGE, SHIFT_RANGE
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if coverage(mid) < level else (lo, mid)
    return hi


def shift_noise(noise: LogNoise, shift: GateShift) -> LogNoise:
    """`noise` with its log variance raised by shift.d_quiet where its gate is 0 and by
    shift.d_event where it is 1 (a model without a gate takes the shift's)."""
    out = LogNoise(**{**noise.__dict__})
    if noise.log_bias_event is None:
        out.gate_z0, out.gate_s = shift.z0, shift.s
        out.log_bias_event = noise.log_bias + shift.d_event
    else:
        out.log_bias_event = noise.log_bias_event + shift.d_event
    out.log_bias = noise.log_bias + shift.d_quiet
    if shift.missed_speed_rpm is not None and shift.missed_lower_n is not None and any(
            v > 0 for v in shift.missed_lower_n):
        out.missed_speed_rpm = np.array(shift.missed_speed_rpm, float)
        out.missed_lower_n = np.array(shift.missed_lower_n, float)
    return out


def refit_beta(z: np.ndarray, y: np.ndarray, w: np.ndarray, like: GatedMean) -> GatedMean:
    """`like` with beta refitted by weighted least squares, its gate (z0, s) kept: a model
    refitted on part of the rows gates the same blocks as the full one, so its quiet and
    ventilating sides (and the noise levels on them) are the same."""
    u = np.asarray(z, float) if like.s <= 0 else np.asarray(z, float) * gate(z, like.z0, like.s)
    beta = float(np.sum(w * u * y) / max(float(np.sum(w * u * u)), 1e-12))
    return GatedMean(beta, like.z0, like.s)


def fit_gated_mean(z: np.ndarray, y: np.ndarray, w: np.ndarray) -> GatedMean:
    """Weighted least-squares g(z) = beta z / (1 + exp(-(|z| - z0) / s)), best of a few starts.

    beta starts from the plain linear fit through 0 and z0 from quantiles of |z|; if the gate
    does not lower the weighted squared residual by 1 %, the plain linear term is returned.
    """
    from scipy.optimize import least_squares

    z, y, sw = np.asarray(z, float), np.asarray(y, float), np.sqrt(np.asarray(w, float))
    if not (np.isfinite(z).all() and np.isfinite(y).all() and np.isfinite(sw).all()):
        raise ValueError("fit_gated_mean: z, y and w must be finite")
    beta = float(np.sum(w * z * y) / max(float(np.sum(w * z * z)), 1e-12))
    best, cost = GatedMean(beta), float(np.sum((sw * (beta * z - y)) ** 2))
    linear_cost = cost
    a = np.abs(z)
    top = float(a.max()) if a.size else 0.0
    if top <= 0.0:
        return best
    s_min = 1e-3 * top
    for q in (0.5, 0.75, 0.9):
        z0 = float(np.quantile(a, q))
        start = [beta, z0, max(0.25 * z0, s_min)]
        fit = least_squares(lambda c: sw * (GatedMean(*c)(z) - y), start,
                            bounds=([-np.inf, 0.0, s_min], [np.inf, top, top]))
        if 2.0 * fit.cost < cost:
            best, cost = GatedMean(*map(float, fit.x)), 2.0 * fit.cost
    return best if cost < (1.0 - MIN_GATE_GAIN) * linear_cost else GatedMean(beta)


def fit_exact(x: np.ndarray, y: np.ndarray, w: np.ndarray, params: GpParams | None = None,
              hyper: Hyper | None = None, keep_inverse: bool = True,
              noise: LogNoise | None = None, mean_term: GatedMean | None = None) -> ExactGp:
    """Exact weighted GP with scikit-learn (hyperparameters fitted unless given); with a
    noise model, row i has noise var(x_i) / w_i instead of sigma^2 / w_i; the GP models
    y - mean_term(x[:, 1])."""
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import ConstantKernel, Matern

    p = params or GpParams()
    mean_term = mean_term or GatedMean()
    y = np.asarray(y, dtype=float) - mean_term(np.asarray(x, dtype=float)[:, 1])
    st = Standardiser(x)
    xs = st(x)
    y_mean, y_std = float(np.mean(y)), float(np.std(y)) or 1.0
    yn = (y - y_mean) / y_std
    h = hyper or fit_hyper(xs, yn, w, p)
    if noise is not None:
        h = Hyper(h.length_scales, h.signal_var, 0.0)
    kernel = (ConstantKernel(h.signal_var, "fixed")
              * Matern(length_scale=h.length_scales, length_scale_bounds="fixed", nu=NU))
    # normalize_y=True divides y by its std, so alpha (a variance of y) is divided by var(y);
    # h.noise_var is already in those normalised units.
    row_noise = h.noise_var if noise is None else noise.var_n2(x) / y_std**2
    gpr = GaussianProcessRegressor(kernel, alpha=row_noise / w, normalize_y=True,
                                   optimizer=None)
    gpr.fit(xs, y)
    k_inv = None
    if keep_inverse:
        l_inv = np.linalg.inv(gpr.L_)
        k_inv = l_inv.T @ l_inv
    return ExactGp(st.mean, st.scale, float(gpr._y_train_mean[0] if np.ndim(gpr._y_train_mean)
                                            else gpr._y_train_mean),
                   float(np.ravel(gpr._y_train_std)[0]), h, np.asarray(x, float), w,
                   np.ravel(gpr.alpha_), k_inv, gpr, noise, mean_term)


def sklearn_predict(gp: ExactGp, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(mean, std of a new measurement) through scikit-learn, noise variance added back."""
    assert gp.sklearn is not None
    xs = (np.asarray(x, dtype=float) - gp.x_mean) / gp.x_scale
    mean, std = gp.sklearn.predict(xs, return_std=True)
    mean = mean + gp.mean_term(np.asarray(x, dtype=float)[:, 1])
    return mean, np.sqrt(std**2 + gp.noise_n2(np.asarray(x, dtype=float)))


@dataclass
class SorGp:
    """Subset-of-regressors GP with m inducing points (weighted), same kernel family."""

    x_mean: np.ndarray
    x_scale: np.ndarray
    y_mean: float
    y_std: float
    hyper: Hyper
    z: np.ndarray  # inducing inputs, standardised
    beta: np.ndarray  # mean weights
    cov: np.ndarray  # posterior covariance of the inducing weights

    @property
    def noise_var_n2(self) -> float:
        return self.hyper.noise_var * self.y_std**2

    def predict(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        xs = (np.asarray(x, dtype=float) - self.x_mean) / self.x_scale
        k = self.hyper.signal_var * matern52(xs, self.z, self.hyper.length_scales)
        mean = self.y_mean + self.y_std * (k @ self.beta)
        var_n = quadratic_rows(k, self.cov) + self.hyper.noise_var
        return mean, self.y_std * np.sqrt(var_n)


def fit_sor(x: np.ndarray, y: np.ndarray, w: np.ndarray, params: GpParams | None = None,
            hyper: Hyper | None = None) -> SorGp:
    """SoR: f(x) = k_m(x) beta, beta ~ N(0, K_mm^-1); cost O(n m^2) and memory O(n m)."""
    from scipy.linalg import cho_factor, cho_solve

    p = params or GpParams()
    st = Standardiser(x)
    xs = st(x)
    y_mean, y_std = float(np.mean(y)), float(np.std(y)) or 1.0
    yn = (y - y_mean) / y_std
    h = hyper or fit_hyper(xs, yn, w, p)
    rng = np.random.default_rng(p.seed)
    m = min(p.inducing, xs.shape[0])
    z = xs[np.sort(rng.choice(xs.shape[0], m, replace=False))]
    kmm = h.signal_var * matern52(z, z, h.length_scales) + 1e-8 * np.eye(m)
    prec = w / h.noise_var
    a = kmm.copy()
    b = np.zeros(m)
    for s in range(0, xs.shape[0], 4096):
        kmn = h.signal_var * matern52(z, xs[s:s + 4096], h.length_scales)
        a += (kmn * prec[s:s + 4096]) @ kmn.T
        b += kmn @ (prec[s:s + 4096] * yn[s:s + 4096])
    c = cho_factor(a)
    beta = cho_solve(c, b)
    cov = cho_solve(c, np.eye(m))
    return SorGp(st.mean, st.scale, y_mean, y_std, h, z, beta, cov)


def interval(mean: np.ndarray, std: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """95 % interval mean +- 1.96 std."""
    return mean - Z95 * std, mean + Z95 * std


__all__ = ["ExactGp", "GpParams", "Hyper", "SorGp", "fit_exact", "fit_hetero", "fit_noise",
           "fit_sor", "interval", "calibrate_gate", "matern52", "shift_noise",
           "sklearn_predict", "variance_parts"]
