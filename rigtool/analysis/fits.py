"""Steady-state thruster model fits with 95 % intervals ([Fossen2011], [Luo2020]; docs/references.md).

All fits are weighted least squares on per-point means with the per-point standard errors,
using the effective-variance method for the error in the regressor (one re-weighting pass).
Thrust fits carry a zero offset and a linear zero drift in time as nuisance terms (see
`fit_directional`): the sensor zero keeps drifting after the rig's last tare. A resumed run
gives each session (start or resume, tared again) its own offset and all one drift (`ZeroLine`).
Intervals stay honest when the errors are larger or less independent than the standard
errors say: the covariance is scaled by the reduced chi-square when it exceeds 1, and, when
the acquisition order is given, computed as a sandwich with AR(1)-correlated errors in that
order (slow drift gives neighbouring points a shared offset), with r1 the lag-1
autocorrelation of the weighted residuals, bias-corrected (stats.py states the rule). Intervals
use Student's t with n_eff - p degrees of freedom, n_eff = n (1 - r1) / (1 + r1). The
thruster-model fits (C_p, C_n) scale by the reduced chi-square both ways once they have
MIN_SCALE_DOF degrees of freedom: the point standard errors are deliberately cautious (the
larger of two estimates), so the residual scatter is the better measure of the error scale.

C_i is a function of several fits (C_p and C_n, or the direct fit against the C_p fit's zero
and the current fit's I_0): its variance is a sandwich over the points of every path a point's
error takes into it (`sandwich_variance`), so errors that cancel (a speed error moves C_p and
C_n together; the thrust noise that set the zero also sets the direct fit) are not counted
twice.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from dataclasses import dataclass

import numpy as np

from rigtool.analysis.stats import (
    MAX_R1_FIT,
    ar1_coefficient,
    effective_sample_size,
    lag1_autocorrelation,
    serially_correlated,
)

RPM_PER_RPS = 60.0
SECONDS_PER_HOUR = 3600.0
DIRECT_MIN_K = 10.0  # direct C_i fit: I - I_0 must exceed this many of its standard errors
MIN_SCALE_DOF = 20  # model fits with this many degrees of freedom take their scale from the scatter
LACK_P = 1e-3  # residuals beyond their stated errors at this chi-square p-value: lack of fit
CUBIC = 3.0  # the textbook exponent of I = C_n |n|^3 + I_0
MIN_LAG_POINTS = 10  # fitted points read while x moved for a lag term to enter
Z95 = 1.96


@dataclass(frozen=True)
class Coefficient:
    """A fitted or derived value with its 95 % interval, unit and fit quality.

    lo/hi is the full interval; `systematic` (same unit as the value) is the allowance for
    what the scatter cannot show, already added in quadrature to lo/hi. The statistical
    interval alone is `stat_lo`/`stat_hi`.
    """

    name: str
    value: float
    lo: float
    hi: float
    unit: str
    n: int = 0
    r2: float = math.nan
    rms: float = math.nan
    rms_unit: str = ""
    note: str = ""
    systematic: float = 0.0
    stat_lo: float | None = None
    stat_hi: float | None = None

    @property
    def statistical(self) -> tuple[float, float]:
        """(lo, hi) of the statistical 95 % interval, without the systematic allowance."""
        return (self.lo if self.stat_lo is None else self.stat_lo,
                self.hi if self.stat_hi is None else self.stat_hi)


@dataclass
class LinearFit:
    """Result of a weighted linear least-squares fit y ~ X beta."""

    beta: np.ndarray
    cov: np.ndarray
    dof: int
    chi2_red: float
    resid: np.ndarray
    influence: np.ndarray  # beta = influence @ y: one row per coefficient, one column per point
    leverage: np.ndarray | None = None  # diagonal of the hat matrix, one value per point
    serial: np.ndarray | None = None  # per coefficient: variance with / without AR(1) errors

    @property
    def hc2_resid(self) -> np.ndarray:
        """Residuals scaled by 1 / sqrt(1 - leverage): their squares are unbiased for the
        points' error variances (HC2), as a residual sandwich needs."""
        return hc2(self.resid, self.leverage)

    def half_width(self, i: int) -> float:
        from scipy import special  # not scipy.stats: 0.6 s more to import

        t = special.stdtrit(max(self.dof, 1), 0.975)
        return float(t * math.sqrt(max(self.cov[i, i], 0.0)))


def wls(design: np.ndarray, y: np.ndarray, sigma: np.ndarray,
        order: np.ndarray | None = None, scale_down: bool = False,
        lack_of_fit: bool = False) -> LinearFit:
    """Weighted LS; covariance scaled for excess scatter and for serial correlation in `order`
    (`scale_down`: also for less scatter than `sigma` says, given MIN_SCALE_DOF).
    `lack_of_fit`: where the residuals exceed their stated errors beyond chance (p < LACK_P)
    with fewer than MIN_SCALE_DOF degrees of freedom, the weights may let one precise point
    decide the fit the others miss; the covariance is then at least that of an equally
    weighted fit with the residuals' own scatter."""
    w = 1.0 / _floor_sigma(sigma, y)
    a = design * w[:, None]
    scale = np.sqrt(np.sum(a**2, axis=0))
    scale[scale == 0] = 1.0
    # Columns are scaled to unit norm first: |n|^3 and a constant differ by ten decades.
    beta_s, *_ = np.linalg.lstsq(a / scale, y * w, rcond=None)
    beta = beta_s / scale
    influence = np.linalg.pinv(a / scale) * w[None, :] / scale[:, None]
    resid = y - design @ beta
    dof = len(y) - design.shape[1]
    chi2_red = float(np.sum((resid * w) ** 2) / dof) if dof > 0 else math.nan
    a_s = a / scale
    bread = white = np.linalg.pinv(a_s.T @ a_s)
    if order is not None and dof > 1:
        sort = np.argsort(order, kind="stable")
        r = (resid * w)[sort]
        raw = lag1_autocorrelation(r)
        r1 = ar1_coefficient(raw, MAX_R1_FIT, len(y)) if serially_correlated(raw, len(y)) else 0.0
        if r1 > 0:
            a_t = a_s[sort]
            bread = bread @ (a_t.T @ _ar1_correlate(a_t, r1)) @ bread
            dof = max(int(effective_sample_size(len(y), r1)) - design.shape[1], 1)
    cov = bread / np.outer(scale, scale)
    if dof > 0 and (chi2_red > 1.0 or (scale_down and len(y) - design.shape[1] >= MIN_SCALE_DOF)):
        cov = cov * chi2_red
    if lack_of_fit:
        cov = _with_lack_of_fit(cov, design, y, len(y) - design.shape[1], chi2_red)
    leverage = np.sum(design * influence.T, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        serial = np.where(np.diag(white) > 0, np.diag(bread) / np.diag(white), 1.0)
    return LinearFit(beta, cov, dof, chi2_red, resid, influence, leverage,
                     np.maximum(np.nan_to_num(serial, nan=1.0), 1.0))


def _with_lack_of_fit(cov: np.ndarray, design: np.ndarray, y: np.ndarray, dof: int,
                      chi2_red: float) -> np.ndarray:
    """`cov` scaled up to the equally weighted fit's (residual scatter as the error) where a
    few points miss the law beyond their errors (see `wls`)."""
    from scipy import special

    if not (0 < dof < MIN_SCALE_DOF and math.isfinite(chi2_red)
            and special.chdtrc(dof, dof * chi2_red) < LACK_P):
        return cov
    scale = np.sqrt(np.sum(design**2, axis=0))
    scale[scale == 0] = 1.0
    d = design / scale
    beta, *_ = np.linalg.lstsq(d, y, rcond=None)
    resid = y - d @ beta
    plain = np.linalg.pinv(d.T @ d) * float(resid @ resid) / dof / np.outer(scale, scale)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(np.diag(cov) > 0, np.diag(plain) / np.diag(cov), 1.0)
    return cov * max(float(np.nanmax(ratio)), 1.0)


def hc2(resid: np.ndarray, leverage: np.ndarray | None) -> np.ndarray:
    """`resid` / sqrt(1 - leverage) (as they are without leverages)."""
    if leverage is None:
        return resid
    return resid / np.sqrt(np.clip(1.0 - leverage, 0.05, 1.0))


def coefficient_correlation(fit_a: LinearFit, i: int, rows_a: np.ndarray, fit_b: LinearFit,
                            j: int, rows_b: np.ndarray) -> float:
    """Correlation of coefficient i of fit_a with coefficient j of fit_b, from the errors of
    the points both fits use (`rows_*`: the point index of each fit row, in time order).

    A cross sandwich of the two fits' residuals with a Bartlett lag window ([NeweyWest1987]): a
    point's speed error moves the residuals of thrust-vs-speed and current-vs-speed together,
    and a slow speed error moves neighbouring points too, so C_p and C_n share it.
    """
    size = int(max(rows_a.max(initial=-1), rows_b.max(initial=-1))) + 1
    ua, ub = np.zeros(size), np.zeros(size)
    ua[rows_a] = fit_a.influence[i] * fit_a.resid
    ub[rows_b] = fit_b.influence[j] * fit_b.resid
    if np.intersect1d(rows_a, rows_b).size < 3:
        return 0.0
    lags = _lags(size)
    va, vb = _long_run(ua, ua, lags), _long_run(ub, ub, lags)
    if va <= 0 or vb <= 0:
        return 0.0
    return float(np.clip(_long_run(ua, ub, lags) / math.sqrt(va * vb), -1.0, 1.0))


def _lags(size: int) -> int:
    """Bartlett window length for `size` points in time order."""
    return int(np.ceil(size ** (1 / 3)))


def _long_run(x: np.ndarray, y: np.ndarray, lags: int) -> float:
    """Long-run covariance ([NeweyWest1987]) of two per-point series (Bartlett weights)."""
    total = float(x @ y)
    for k in range(1, min(lags, x.size - 1) + 1):
        total += (1 - k / (lags + 1)) * float(x[:-k] @ y[k:] + y[:-k] @ x[k:])
    return total


Part = tuple[np.ndarray, np.ndarray]  # (point index of each row, error contribution per row)


def sandwich_variance(parts: list[Part], n_params: int) -> tuple[float, int]:
    """Variance of an estimate whose error is the sum of `parts`, and its degrees of freedom.

    Each part gives, for the points of one fit, the fit residual (HC2-scaled, see
    `LinearFit.hc2_resid`) times the weight that point has in the estimate along one path;
    contributions of a point are added before squaring (paths that share a point's error
    cancel or add as they should). Errors are taken as independent between points: scale the
    result for serial correlation (`LinearFit.serial`). A [NeweyWest1987] lag window would not
    do: a fit's weighted residuals sum to zero, so their lagged products are biased low.
    """
    size = int(max(rows.max(initial=-1) for rows, _ in parts)) + 1
    u = np.zeros(size)
    for rows, values in parts:
        np.add.at(u, rows, np.nan_to_num(values))
    n = int(np.unique(np.concatenate([rows for rows, _ in parts])).size)
    return float(u @ u), max(n - n_params, 1)


def t95(dof: int) -> float:
    """Two-sided 95 % quantile of Student's t."""
    from scipy import special

    return float(special.stdtrit(max(dof, 1), 0.975))


def with_interval(c: Coefficient, half_width: float) -> Coefficient:
    """`c` with the symmetric 95 % interval value -+ `half_width` (NaN: none)."""
    return dataclasses.replace(c, lo=c.value - half_width, hi=c.value + half_width)


def _ar1_correlate(a: np.ndarray, r1: float) -> np.ndarray:
    """R @ a for the AR(1) correlation R_ij = r1^|i - j|, in O(n): R's inverse is tridiagonal
    ((1 + r1^2) inside, 1 at both ends, -r1 beside the diagonal, all over 1 - r1^2), so R @ a
    is one banded solve (scipy.signal's recursive filters cost 0.8 s to import)."""
    from scipy.linalg import solve_banded

    n = len(a)
    if n < 2:
        return np.array(a, dtype=float)
    bands = np.empty((3, n))
    bands[0], bands[2] = -r1, -r1
    bands[1] = 1.0 + r1 * r1
    bands[1, [0, -1]] = 1.0
    return solve_banded((1, 1), bands, (1.0 - r1 * r1) * a)


def _floor_sigma(sigma: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Replace zero/NaN standard errors so one noiseless point cannot take all the weight."""
    s = np.asarray(sigma, dtype=float)
    good = np.isfinite(s) & (s > 0)
    scale = np.median(s[good]) if good.any() else 1e-9 * max(np.max(np.abs(y)), 1.0)
    return np.where(good, np.maximum(s, 1e-3 * scale), scale)


def _quality(y: np.ndarray, resid: np.ndarray) -> tuple[float, float]:
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    ss_res = float(np.sum(resid**2))
    r2 = 1.0 - ss_res / ss_tot if ss_tot > 0 else math.nan
    return r2, math.sqrt(ss_res / len(y))


def _coef(name: str, fit: LinearFit, i: int, unit: str, y: np.ndarray, rms_unit: str,
          note: str) -> Coefficient:
    value = float(fit.beta[i])
    hw = fit.half_width(i) if fit.dof > 0 else math.nan
    r2, rms = _quality(y, fit.resid)
    return Coefficient(name, value, value - hw, value + hw, unit, len(y), r2, rms, rms_unit, note)


def fitted(name: str, fit: LinearFit, i: int, unit: str, y: np.ndarray, rms_unit: str,
           note: str = "") -> Coefficient:
    """Coefficient `i` of a fit with its 95 % interval (Student's t on the fit's dof) and quality."""
    return _coef(name, fit, i, unit, y, rms_unit, note)


Cov2 = tuple[tuple[float, float], tuple[float, float]]


def session_index(t_s: np.ndarray, starts: tuple[float, ...]) -> np.ndarray:
    """Per time, its session: how many of the session start times `starts` lie before it."""
    return np.searchsorted(np.asarray(starts, dtype=float), np.asarray(t_s, dtype=float),
                           side="left")


def occupied_starts(t_s: np.ndarray, starts: tuple[float, ...]) -> tuple[float, ...]:
    """The starts of the sessions after the first that hold some of `t_s`: a session without
    any of them joins the one before it (the first one with any, for those before it)."""
    if not starts or not np.size(t_s):
        return ()
    held = np.unique(session_index(t_s, starts))
    return tuple(float(starts[k - 1]) for k in held[1:])


@dataclass(frozen=True)
class ZeroLine:
    """Estimated thrust zero: offset_n at t_ref_s plus a linear drift (N/s), and its source.

    `cov` is the 2x2 covariance of (offset_n, drift_n_per_s) when the line was fitted, so a
    test against the zero can allow for how well the zero is known at each time.

    A resumed run has one session per start or resume (a tare, or a re-opened sensor, sets
    the zero again): the zero is then a_k + drift (t - t_ref) in session k, one drift for all.
    offset_n and `cov` are the first session's; `session_starts_s` are the times the later
    sessions begin, `session_offsets_n` their offsets at t_ref_s, and `session_cov` the full
    covariance of (offset_n, *session_offsets_n, drift_n_per_s). One session: all empty.
    """

    offset_n: float
    drift_n_per_s: float
    t_ref_s: float
    source: str
    cov: Cov2 | None = None
    session_starts_s: tuple[float, ...] = ()
    session_offsets_n: tuple[float, ...] = ()
    session_cov: tuple[tuple[float, ...], ...] | None = None

    @property
    def offsets(self) -> np.ndarray:
        """The offset (N, at t_ref_s) of every session, the first one first."""
        return np.array([self.offset_n, *self.session_offsets_n], dtype=float)

    def session_of(self, t_s: np.ndarray) -> np.ndarray:
        """The session (0 = first) each time in `t_s` belongs to."""
        return session_index(t_s, self.session_starts_s)

    def at(self, t_s: np.ndarray) -> np.ndarray:
        """The zero (N) at the times `t_s`, each with its session's offset."""
        t = np.asarray(t_s, dtype=float)
        if not self.session_starts_s:
            return self.offset_n + self.drift_n_per_s * (t - self.t_ref_s)
        return self.offsets[self.session_of(t)] + self.drift_n_per_s * (t - self.t_ref_s)

    def var_at(self, t_s: np.ndarray) -> np.ndarray:
        """Variance (N^2) of the zero at `t_s`; 0 where the line carries no covariance."""
        dt = np.asarray(t_s, dtype=float) - self.t_ref_s
        if self.session_starts_s:
            if self.session_cov is None:
                return np.zeros(dt.shape)
            c = np.array(self.session_cov, dtype=float)
            k = self.session_of(t_s)
            return np.maximum(c[k, k] + 2 * c[k, -1] * dt + c[-1, -1] * dt**2, 0.0)
        if self.cov is None:
            return np.zeros(dt.shape)
        (a, b), (_, d) = self.cov
        return np.maximum(a + 2 * b * dt + d * dt**2, 0.0)


def session_line(offsets: np.ndarray, drift: float, t_ref: float, source: str,
                 cov: np.ndarray | None, starts: tuple[float, ...]) -> ZeroLine:
    """A ZeroLine from per-session `offsets` (N), `drift` (N/s) and the covariance `cov` of
    (offsets..., drift) (N, N/s; None: not known); one session gives the plain line."""
    cov2 = None
    if cov is not None:
        idx = [0, len(offsets)]
        c = cov[np.ix_(idx, idx)]
        cov2 = ((float(c[0, 0]), float(c[0, 1])), (float(c[1, 0]), float(c[1, 1])))
    if len(offsets) == 1:
        return ZeroLine(float(offsets[0]), float(drift), t_ref, source, cov2)
    full = None if cov is None else tuple(tuple(float(v) for v in row) for row in cov)
    return ZeroLine(float(offsets[0]), float(drift), t_ref, source, cov2, tuple(starts),
                    tuple(float(v) for v in offsets[1:]), full)


def session_columns(t: np.ndarray, starts: tuple[float, ...]) -> tuple[np.ndarray, ...]:
    """One offset column per session of `starts` (an indicator of its times; a single column
    of ones for one session)."""
    k = session_index(t, starts)
    return tuple((k == j).astype(float) for j in range(len(starts) + 1))


@dataclass
class DirectionalFit:
    """Joint fit y = c_fwd x [fwd] + c_rev x [rev] + a + b (t - t_ref) over both directions.

    x is signed like y (e.g. |n| n), so both coefficients are positive for a normal thruster.
    The offset a and drift b absorb the thrust zero left after taring (sensor drift), shared
    by the two directions; they are nuisance terms, not part of the thruster model.
    """

    fit: LinearFit
    columns: list[str]
    masks: dict[str, np.ndarray]
    used: np.ndarray
    y: np.ndarray
    t_ref_s: float
    fixed_zero: ZeroLine | None = None  # zero given to the fit (then no offset/drift columns)
    session_starts: tuple[float, ...] = ()  # later sessions' start times (one offset each)

    @property
    def offset_columns(self) -> list[int]:
        """Column index of each session's offset, the first session first."""
        return [self.columns.index("offset")] + [
            self.columns.index(f"offset_{k}") for k in range(1, len(self.session_starts) + 1)]

    def coefficient(self, key: str, name: str, unit: str, note: str) -> Coefficient:
        i = self.columns.index(key)
        m = self.masks[key][self.used]
        r2, rms = _quality(self.y[m], self.fit.resid[m])
        value = float(self.fit.beta[i])
        hw = self.fit.half_width(i) if self.fit.dof > 0 else math.nan
        return Coefficient(name, value, value - hw, value + hw, unit, int(m.sum()), r2, rms,
                           "N", note)

    @property
    def zero(self) -> ZeroLine:
        if self.fixed_zero is not None:
            return self.fixed_zero
        if self.session_starts:
            return self._session_zero()
        beta = dict(zip(self.columns, self.fit.beta, strict=True))
        i = self.columns.index("offset")
        cov = ((float(self.fit.cov[i, i]), 0.0), (0.0, 0.0))
        if "drift" in self.columns:
            j = self.columns.index("drift")
            c = self.fit.cov[np.ix_([i, j], [i, j])] / np.array([[1, SECONDS_PER_HOUR]] * 2)
            c = c / np.array([[1], [SECONDS_PER_HOUR]])
            cov = ((float(c[0, 0]), float(c[0, 1])), (float(c[1, 0]), float(c[1, 1])))
        return ZeroLine(float(beta["offset"]), float(beta.get("drift", 0.0)) / SECONDS_PER_HOUR,
                        self.t_ref_s, "model fit", cov)

    def _session_zero(self) -> ZeroLine:
        """The zero with one offset per session and the common drift, in N and N/s."""
        idx = self.offset_columns
        scale = np.ones(len(idx) + 1)
        if "drift" in self.columns:
            idx = [*idx, self.columns.index("drift")]
            scale[-1] = SECONDS_PER_HOUR
        cov = np.zeros((scale.size, scale.size))
        cov[:len(idx), :len(idx)] = self.fit.cov[np.ix_(idx, idx)]
        cov = cov / np.outer(scale, scale)
        beta = np.append(self.fit.beta[self.offset_columns],
                         self.fit.beta[idx[-1]] if "drift" in self.columns else 0.0)
        return session_line(beta[:-1], float(beta[-1] / scale[-1]), self.t_ref_s, "model fit",
                            cov, self.session_starts)

    def lag_coefficient(self) -> Coefficient | None:
        """The lag L (s) of y behind x, from the "lag" column (-c L) and the first direction's
        c, with a first-order 95 % interval (None without a lag column)."""
        if "lag" not in self.columns:
            return None
        j, i = self.columns.index("lag"), 0
        c, beta = float(self.fit.beta[i]), float(self.fit.beta[j])
        if not c > 0:
            return None
        lag = -beta / c
        grad = np.array([lag / c, -1.0 / c])  # d lag / d (c, beta)
        var = float(grad @ self.fit.cov[np.ix_([i, j], [i, j])] @ grad)
        hw = t95(self.fit.dof) * math.sqrt(max(var, 0.0)) if self.fit.dof > 0 else math.nan
        r2, rms = _quality(self.y, self.fit.resid)
        return Coefficient("thrust_lag_s", lag, lag - hw, lag + hw, "s", len(self.y), r2, rms,
                           "N", "thrust read this long after the speed (negative: before), "
                           "fitted with C_p on the points read while the speed moved")

    def zero_coefficients(self) -> list[Coefficient]:
        """f_0 (N, at t_ref) and zero_drift (N/h) as coefficients."""
        r2, rms = _quality(self.y, self.fit.resid)
        n = len(self.y)
        out = []
        for key, name, unit in (("offset", "f_0", "N"), ("drift", "zero_drift", "N/h")):
            if key in self.columns:
                i = self.columns.index(key)
                value = float(self.fit.beta[i])
                hw = self.fit.half_width(i) if self.fit.dof > 0 else math.nan
                note = (f"thrust zero left after taring, fitted with C_p (at t = "
                        f"{self.t_ref_s:.1f} s)" if key == "offset" else
                        "drift of that zero over the run")
                if self.session_starts:
                    note += (f"; {len(self.session_starts) + 1} sessions (run resumed): "
                             "f_0 is the first one's offset, one drift for all"
                             if key == "offset" else
                             f", common to its {len(self.session_starts) + 1} sessions")
                out.append(Coefficient(name, value, value - hw, value + hw, unit, n, r2, rms,
                                       "N", note))
        return out


def fit_directional(x: np.ndarray, y: np.ndarray, se_y: np.ndarray, dx_se: np.ndarray | None,
                    t_s: np.ndarray, masks: dict[str, np.ndarray],
                    min_points: int = 3, zero: ZeroLine | None = None,
                    sessions: tuple[float, ...] = (), drift: bool = True,
                    lag_rate: np.ndarray | None = None) -> DirectionalFit | None:
    """Fit y = sum_k c_k x [mask_k] + a + b (t - t_ref) by WLS (effective variance for dx_se).

    Directions with fewer than `min_points` points are left out; the drift term only enters
    when `drift` (the design separates it from the law: drift_design.py), the points span
    time and leave enough degrees of freedom. Errors are treated as
    serially correlated in time (see module docstring). With `zero` given, y - zero(t) is
    fitted without the offset and drift terms. `sessions` are the start times of a resumed
    run's later sessions: each session that holds points gets its own offset a_k (columns
    "offset", "offset_1", ...), the drift b stays one for all. `lag_rate`: dx/dt per point
    where x moves while the point is read (a ramp's bins; NaN where held): y read a lag L
    after (or before) x is y(t) = c x(t - L) ~ c x - c L dx/dt, so a column "lag" (-c L)
    enters where MIN_LAG_POINTS fitted points move; the lag is common to the ramp's bins
    and does not average out over them.
    """
    keys = [k for k, m in masks.items() if m.sum() >= min_points]
    if not keys:
        return None
    used = np.logical_or.reduce([masks[k] for k in keys])
    t = t_s[used]
    t_ref = float(np.mean(t))
    cols = [np.where(masks[k][used], x[used], 0.0) for k in keys]
    names = list(keys)
    yy, se = y[used], se_y[used]
    starts: tuple[float, ...] = ()
    if zero is not None:
        yy = yy - zero.at(t)
    else:
        starts = occupied_starts(t, sessions)
        names += ["offset"] + [f"offset_{k}" for k in range(1, len(starts) + 1)]
        cols += session_columns(t, starts)
        if drift and np.ptp(t) > 0 and used.sum() >= len(cols) + 4:
            cols.append((t - t_ref) / SECONDS_PER_HOUR)
            names.append("drift")
    rate = None if lag_rate is None else lag_rate[used]
    if (rate is not None and np.sum(np.isfinite(rate) & (rate != 0)) >= MIN_LAG_POINTS
            and used.sum() >= len(cols) + 4):
        cols.append(np.nan_to_num(rate))
        names.append("lag")
    design = np.column_stack(cols)
    fit = wls(design, yy, se, t, scale_down=True, lack_of_fit=True)
    if dx_se is not None:
        slope = sum(np.where(masks[k][used], fit.beta[i], 0.0) for i, k in enumerate(keys))
        fit = wls(design, yy, np.sqrt(se**2 + (slope * np.nan_to_num(dx_se[used])) ** 2), t,
                  scale_down=True, lack_of_fit=True)
    if zero is not None:
        _add_zero_error(fit, zero, t)
    return DirectionalFit(fit, names, masks, used, yy, t_ref, zero, starts)


def _add_zero_error(fit: LinearFit, zero: ZeroLine, t: np.ndarray) -> None:
    """Add to `fit.cov` what the given zero's own error moves the coefficients by: every point
    shares it, so it does not average out over the points (a resumed run's zero: not added)."""
    if zero.cov is None or zero.session_starts_s:
        return
    sens = np.column_stack([fit.influence @ np.ones(t.size),
                            fit.influence @ (t - zero.t_ref_s)])
    fit.cov = fit.cov + sens @ np.array(zero.cov, dtype=float) @ sens.T


def fit_thrust_speed(n_rpm: np.ndarray, f_n: np.ndarray, se_f: np.ndarray,
                     se_n: np.ndarray | None, t_s: np.ndarray,
                     masks: dict[str, np.ndarray],
                     zero: ZeroLine | None = None,
                     sessions: tuple[float, ...] = (), drift: bool = True,
                     lag_rate: np.ndarray | None = None) -> DirectionalFit | None:
    """f = C_p |n| n with C_p per direction (`masks`: "fwd"/"rev" point masks) + zero terms,
    an offset per session of `sessions` (or against a given `zero`); a drift only with
    `drift`; a lag between thrust and speed where `lag_rate` (d(n|n|)/dt) says the points
    moved (fit_directional)."""
    dx = None if se_n is None else 2 * np.abs(n_rpm) * se_n
    return fit_directional(np.abs(n_rpm) * n_rpm, f_n, se_f, dx, t_s, masks, zero=zero,
                           sessions=sessions, drift=drift, lag_rate=lag_rate)


def thrust_coefficient(cp: Coefficient, diameter_m: float, density_kg_m3: float,
                       name: str) -> Coefficient:
    """K_T = f / (rho n^2 D^4) with n in rev/s, from C_p in N/(r/min)^2."""
    k = RPM_PER_RPS**2 / (density_kg_m3 * diameter_m**4)
    return Coefficient(name, cp.value * k, cp.lo * k, cp.hi * k, "1", cp.n, cp.r2, cp.rms,
                       cp.rms_unit, f"K_T = C_p * 3600 / (rho D^4), D = {diameter_m:g} m, "
                       f"rho = {density_kg_m3:g} kg/m^3")


def fit_current_speed(n_rpm: np.ndarray, i_a: np.ndarray, se_i: np.ndarray,
                      se_n: np.ndarray | None, order: np.ndarray | None = None,
                      exponent: float = CUBIC) -> tuple[Coefficient, Coefficient, LinearFit]:
    """C_n (A/(r/min)^3) and idle current I_0 (A) in I = C_n |n|^3 + I_0 (linear in |n|^3),
    and the fit they come from; with another `exponent` k, C (A/(r/min)^k) and I_0 of
    I = C |n|^k + I_0 with k held."""
    u = np.abs(n_rpm)
    design = np.column_stack([u**exponent, np.ones_like(u)])
    fit = wls(design, i_a, se_i, order, scale_down=True)
    if se_n is not None:
        slope = fit.beta[0] * exponent * u ** (exponent - 1)
        sigma = np.sqrt(se_i**2 + (slope * np.nan_to_num(se_n)) ** 2)
        fit = wls(design, i_a, sigma, order, scale_down=True)
    if exponent == CUBIC:
        note = "I = C_n |n|^3 + I_0"
        return (_coef("C_n", fit, 0, "A/(r/min)^3", i_a, "A", note),
                _coef("I_0", fit, 1, "A", i_a, "A", note), fit)
    note = f"I = C |n|^k + I_0 with k = {exponent:.4g} held"
    return (_coef("C_free", fit, 0, "A/(r/min)^k", i_a, "A", note),
            _coef("I_0_free", fit, 1, "A", i_a, "A", note), fit)


def fit_current_exponent(n_rpm: np.ndarray, i_a: np.ndarray, se_i: np.ndarray,
                         c_n: float, i_0: float) -> tuple[Coefficient, ...]:
    """Free exponent fit I = C |n|^k + I_0 by nonlinear LS, started from the cubic fit.

    |n| is scaled by its maximum so the parameters are of order one; C is converted back.
    """
    from scipy import optimize, special

    u = np.abs(n_rpm)
    u_ref = float(u.max())
    x = u / u_ref
    sigma = _floor_sigma(se_i, i_a)

    def model(x: np.ndarray, a: float, k: float, i0: float) -> np.ndarray:
        return a * x**k + i0

    p0 = (max(c_n * u_ref**3, 1e-9), 3.0, i_0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optimize.OptimizeWarning)
        popt, pcov = optimize.curve_fit(model, x, i_a, p0=p0, sigma=sigma, absolute_sigma=True,
                                        bounds=([0.0, 0.3, -np.inf], [np.inf, 8.0, np.inf]))
    resid = i_a - model(x, *popt)
    dof = len(u) - 3
    chi2_red = float(np.sum((resid / sigma) ** 2) / dof) if dof > 0 else math.nan
    if dof > 0 and (chi2_red > 1.0 or dof >= MIN_SCALE_DOF):
        pcov = pcov * chi2_red
    t = special.stdtrit(max(dof, 1), 0.975)
    a, k, i0 = popt
    # C = a / u_ref^k; log C = log a - k log u_ref; delta method on (a, k).
    grad = np.array([1.0 / a if a > 0 else math.nan, -math.log(u_ref)])
    var_log_c = float(grad @ pcov[:2, :2] @ grad)
    c = a / u_ref**k
    hw_log = t * math.sqrt(max(var_log_c, 0.0)) if dof > 0 else math.nan
    r2, rms = _quality(i_a, resid)
    hw = [t * math.sqrt(max(pcov[i, i], 0.0)) if dof > 0 else math.nan for i in range(3)]
    note = "I = C |n|^k + I_0, k free (physics: 3)"
    n = len(u)
    return (
        Coefficient("k_free", float(k), float(k - hw[1]), float(k + hw[1]), "1", n, r2, rms, "A",
                    note),
        Coefficient("C_free", float(c), float(c * _exp(-hw_log)), float(c * _exp(hw_log)),
                    "A/(r/min)^k", n, r2, rms, "A", note),
        Coefficient("I_0_free", float(i0), float(i0 - hw[2]), float(i0 + hw[2]), "A", n, r2, rms,
                    "A", note),
    )


def current_power_unit(exponent: float = CUBIC) -> str:
    """Unit of C_i for the current law I = C |n|^k + I_0: N/A^(2/3) for k = 3, else N/A^(2/k)."""
    return "N/A^(2/3)" if exponent == CUBIC else "N/A^(2/k)"


def _exp(x: float) -> float:
    """exp that saturates at inf instead of raising (an interval too wide to state)."""
    return math.exp(x) if x < 709.0 else math.inf


def current_law_influence(n_rpm: np.ndarray, i_a: np.ndarray, se_i: np.ndarray, c: float,
                          k: float, i_0: float) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                         np.ndarray]:
    """For I = C |n|^k + I_0 fitted with k free (as `fit_current_exponent` weights it): the
    residuals and, per point, the influence of its residual on log C, on k and on I_0
    (weighted least squares linearised at the estimates); residuals HC2-scaled."""
    u = np.abs(n_rpm)
    w = 1.0 / _floor_sigma(se_i, i_a)
    power = np.where(u > 0, u, 1.0) ** k
    jac = np.column_stack([power, c * power * np.log(np.where(u > 0, u, 1.0)), np.ones(u.size)])
    a = jac * w[:, None]
    scale = np.sqrt(np.sum(a**2, axis=0))
    scale[scale == 0] = 1.0
    influence = np.linalg.pinv(a / scale) * w[None, :] / scale[:, None]
    resid = hc2(i_a - (c * power + i_0), np.sum(jac * influence.T, axis=1))
    return resid, influence[0] / c, influence[1], influence[2]


def derive_thrust_current(cp: Coefficient, cn: Coefficient, name: str,
                          rho: float = 0.0, exponent: float = CUBIC) -> Coefficient:
    """C_i = C_p / C_n^(2/3) (N/A^(2/3)), statistical interval by first-order propagation of
    the statistical intervals of C_p and C_n with their correlation `rho`.

    From f = C_p n^2 and I - I_0 = C_n |n|^3: f = C_i (I - I_0)^(2/3). A common speed error
    moves C_p and C_n the same way (rho > 0), and cancels in the ratio. With the current law
    I = C |n|^k + I_0 (`exponent` k, `cn` its C), C_i = C_p / C^(2/k) and f = C_i (I - I_0)^(2/k).
    """
    unit = current_power_unit(exponent)
    if cn.value <= 0 or cp.value <= 0:
        return Coefficient(name, math.nan, math.nan, math.nan, unit, min(cp.n, cn.n),
                           note="not derivable: C_p or C_n not positive")
    power = 2 / exponent
    value = cp.value / cn.value**power
    (p_lo, p_hi), (n_lo, n_hi) = cp.statistical, cn.statistical
    rel_p = (p_hi - p_lo) / 2 / cp.value
    rel_n = power * (n_hi - n_lo) / 2 / cn.value
    hw = value * math.sqrt(max(rel_p**2 + rel_n**2 - 2 * rho * rel_p * rel_n, 0.0))
    note = ("derived: C_p / C_n^(2/3); f = C_i (I - I_0)^(2/3)" if exponent == CUBIC else
            f"derived: C_p / C_free^(2/k); f = C_i (I - I_0_free)^(2/k), k = {exponent:.4g}")
    return Coefficient(name, value, value - hw, value + hw, unit, min(cp.n, cn.n), note=note)


def fit_thrust_current(i_a: np.ndarray, i_0: float, f_n: np.ndarray, se_f: np.ndarray,
                       se_i: np.ndarray | None, t_s: np.ndarray,
                       masks: dict[str, np.ndarray], zero: ZeroLine | None = None,
                       se_i0: float = 0.0, power: float = 2 / 3) -> DirectionalFit | None:
    """f = +-C_i (I - I_0)^(2/3) fitted directly, C_i per direction, with the zero terms
    (or against a given `zero`: the C_p fit's, which the low-current points cannot bias).

    The sign is + for the "fwd" mask and - for "rev" (the current gives no direction). Only
    points whose I - I_0 exceeds DIRECT_MIN_K times its error (point SE and I_0's) enter:
    nearer I_0 the power 2/3 turns current noise into thrust error no linearisation holds.
    The error of I_0 itself is shared by all points: propagate it separately. `power` is
    2/k for the current law I = C |n|^k + I_0.
    """
    d = i_a - i_0
    se_point = np.nan_to_num(se_i) if se_i is not None else np.zeros(d.size)
    clear = d > DIRECT_MIN_K * np.sqrt(se_point**2 + se_i0**2)
    masks = {k: v & clear for k, v in masks.items()}
    d = np.where(clear, d, 0.0)
    sign = np.where(masks.get("rev", np.zeros(d.size, bool)), -1.0, 1.0)
    dx = None
    if se_i is not None:
        dx = np.where(clear, power * np.where(clear, d, 1.0) ** (power - 1) * se_point, 0.0)
    return fit_directional(sign * d**power, f_n, se_f, dx, t_s, masks, zero=zero)


def with_systematic(c: Coefficient, rel: float) -> Coefficient:
    """`c` with rel * |value| added in quadrature to both sides of its interval.

    For what the scatter cannot show: the scale calibration of the force sensor and of the
    speed/current feedback.
    """
    if rel <= 0 or not math.isfinite(c.value):
        return c
    extra = rel * abs(c.value)
    return dataclasses.replace(
        c, lo=c.value - math.hypot(c.value - c.lo, extra),
        hi=c.value + math.hypot(c.hi - c.value, extra), systematic=extra, stat_lo=c.lo,
        stat_hi=c.hi)


def with_bound(c: Coefficient, rel: float) -> Coefficient:
    """`c` with rel * |value| added to both sides of its interval, not in quadrature: a
    declared bound (a datasheet's maximum error) may be reached, and then only the scatter's
    own interval can hold the truth."""
    if rel <= 0 or not math.isfinite(c.value):
        return c
    extra = rel * abs(c.value)
    stat_lo, stat_hi = c.statistical
    return dataclasses.replace(c, lo=c.lo - extra, hi=c.hi + extra,
                               systematic=c.systematic + extra, stat_lo=stat_lo,
                               stat_hi=stat_hi)


def residual_spread(resid: np.ndarray, name: str, note: str, *, interval: bool) -> Coefficient:
    """RMS of residuals (N) as a coefficient; chi-square 95 % interval when `interval`."""
    from scipy import special

    r = resid[np.isfinite(resid)]
    n = r.size
    if n == 0:
        return Coefficient(name, math.nan, math.nan, math.nan, "N", 0, note=note)
    s = float(math.sqrt(np.mean(r**2)))
    lo = hi = math.nan
    if interval and n > 1:
        lo = s * math.sqrt(n / special.chdtri(n, 0.025))  # chi2 quantiles
        hi = s * math.sqrt(n / special.chdtri(n, 0.975))
    return Coefficient(name, s, lo, hi, "N", n, note=note)
