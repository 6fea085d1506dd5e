"""QCTM-GP: weighted Matern-5/2 GP on standardised (n_p, I, h), exact and sparse (SoR) forms.

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
from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_factor, cho_solve
from sklearn.exceptions import ConvergenceWarning
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel

from rigtool.models import Z95, matern52

NU = 2.5


@dataclass(frozen=True)
class GpParams:
    """GP fitting options (recorded with the results)."""

    hyper_n: int = 800  # points used for the hyperparameter search
    n_restarts: int = 1
    seed: int = 0
    inducing: int = 300  # inducing points of the sparse (SoR) variant


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
    rng = np.random.default_rng(p.seed)
    good = np.flatnonzero(w >= 0.5)
    pool = good if good.size >= min(p.hyper_n, 50) else np.arange(yn.size)
    sub = pool if pool.size <= p.hyper_n else np.sort(rng.choice(pool, p.hyper_n, replace=False))
    kernel = (ConstantKernel(1.0, (1e-3, 1e3))
              * Matern(length_scale=np.ones(xs.shape[1]), length_scale_bounds=(1e-3, 1e3), nu=NU)
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

    @property
    def noise_var_n2(self) -> float:
        """sigma^2 of a new measurement at weight 1 (N^2)."""
        return self.hyper.noise_var * self.y_std**2

    def predict(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(mean, std of a new measurement) in N, numpy only."""
        xs = (np.asarray(x, dtype=float) - self.x_mean) / self.x_scale
        xt = (self.x_train - self.x_mean) / self.x_scale
        k = self.hyper.signal_var * matern52(xs, xt, self.hyper.length_scales)
        mean = self.y_mean + self.y_std * (k @ self.alpha)
        var_n = self.hyper.signal_var + self.hyper.noise_var
        if self.k_inv is not None:
            var_n = var_n - np.einsum("ij,jk,ik->i", k, self.k_inv, k)
        return mean, self.y_std * np.sqrt(np.maximum(var_n, 0.0))


def fit_exact(x: np.ndarray, y: np.ndarray, w: np.ndarray, params: GpParams | None = None,
              hyper: Hyper | None = None, keep_inverse: bool = True) -> ExactGp:
    """Exact weighted GP with scikit-learn (hyperparameters fitted unless given)."""
    p = params or GpParams()
    st = Standardiser(x)
    xs = st(x)
    y_mean, y_std = float(np.mean(y)), float(np.std(y)) or 1.0
    yn = (y - y_mean) / y_std
    h = hyper or fit_hyper(xs, yn, w, p)
    kernel = (ConstantKernel(h.signal_var, "fixed")
              * Matern(length_scale=h.length_scales, length_scale_bounds="fixed", nu=NU))
    # normalize_y=True divides y by its std, so alpha (a variance of y) is divided by var(y);
    # h.noise_var is already in those normalised units.
    gpr = GaussianProcessRegressor(kernel, alpha=h.noise_var / w, normalize_y=True,
                                   optimizer=None)
    gpr.fit(xs, y)
    k_inv = None
    if keep_inverse:
        l_inv = np.linalg.inv(gpr.L_)
        k_inv = l_inv.T @ l_inv
    return ExactGp(st.mean, st.scale, float(gpr._y_train_mean[0] if np.ndim(gpr._y_train_mean)
                                            else gpr._y_train_mean),
                   float(np.ravel(gpr._y_train_std)[0]), h, np.asarray(x, float), w,
                   np.ravel(gpr.alpha_), k_inv, gpr)


def sklearn_predict(gp: ExactGp, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(mean, std of a new measurement) through scikit-learn, noise variance added back."""
    assert gp.sklearn is not None
    xs = (np.asarray(x, dtype=float) - gp.x_mean) / gp.x_scale
    mean, std = gp.sklearn.predict(xs, return_std=True)
    return mean, np.sqrt(std**2 + gp.noise_var_n2)


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
        var_n = np.einsum("ij,jk,ik->i", k, self.cov, k) + self.hyper.noise_var
        return mean, self.y_std * np.sqrt(var_n)


def fit_sor(x: np.ndarray, y: np.ndarray, w: np.ndarray, params: GpParams | None = None,
            hyper: Hyper | None = None) -> SorGp:
    """SoR: f(x) = k_m(x) beta, beta ~ N(0, K_mm^-1); cost O(n m^2) and memory O(n m)."""
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


__all__ = ["ExactGp", "GpParams", "Hyper", "SorGp", "fit_exact", "fit_sor", "interval",
           "matern52", "sklearn_predict"]
