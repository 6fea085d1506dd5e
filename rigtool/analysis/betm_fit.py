"""Fitting the BETM (rigtool.models.betm) to a deep calibration: inverse-variance fusion of speed-
and current-based thrust ([Luo2020], docs/references.md).

f_n = C_p |n| n (C_p per direction), f_i = s C_i (I - I_0)^(2/3) with s the sign of the speed;
both are fused with a prior N(u0, sigma0^2). The consistency test compares the normalised
distance d = |f_n - f_i| / sqrt(sigma_n^2 + sigma_i^2) with gamma: when d > gamma the current
estimate (the noisier one) is dropped for that sample. The estimator variances are those of
the deep calibration's residuals, split into the two estimators' own errors and the force
measurement noise (see `split_variances`), because both residuals share the force noise.
"""

from __future__ import annotations

import math

import numpy as np

from rigtool.analysis.results import CalibrationResult, DepthSection, EstimatorErrors
from rigtool.errors import UsageError
from rigtool.models.betm import Betm


def split_variances(e_n: np.ndarray, e_i: np.ndarray) -> tuple[float, float, float]:
    """(sigma_n, sigma_i, sigma_meas) from residuals e_n = f - f_n and e_i = f - f_i.

    Both residuals contain the force noise m: var(e_n) = s_n^2 + m^2, var(e_i) = s_i^2 + m^2,
    var(e_n - e_i) = s_n^2 + s_i^2 (three-cornered hat), assuming independent errors.
    """
    ok = np.isfinite(e_n) & np.isfinite(e_i)
    vn, vi = float(np.var(e_n[ok])), float(np.var(e_i[ok]))
    vd = float(np.var((e_n - e_i)[ok]))
    floor = 1e-6 * max(vn, vi, 1e-12)
    s_n2 = max((vn - vi + vd) / 2, floor)
    s_i2 = max((vi - vn + vd) / 2, floor)
    m2 = max((vn + vi - vd) / 2, 0.0)
    return math.sqrt(s_n2), math.sqrt(s_i2), math.sqrt(m2)


def deep_section(cal: CalibrationResult) -> DepthSection:
    """The deepest section of a calibration with BETM coefficients (C_p, C_n, C_i)."""
    need = ("C_p_fwd", "C_n", "I_0", "C_i_fwd_direct")
    ok = [s for s in cal.sections if all(k in s.fits for k in need)]
    if not ok:
        raise UsageError(f"run {cal.run_id} has no depth with C_p, C_n and C_i fits: "
                         "use a deep, full-range calibration run as --base")
    return max(ok, key=lambda s: -math.inf if s.depth_m is None else s.depth_m)


def voltage_law_b(cal: CalibrationResult, sec: DepthSection) -> float:
    """Exponent b of the C_n(U) law at the section's depth (NaN: no voltage sweep there)."""
    if sec.voltage_v is None:
        return math.nan
    return next((law.b.value for law in cal.voltage_laws if law.depth_m == sec.depth_m),
                math.nan)


def betm_from_section(sec: DepthSection, **kw: float) -> Betm:
    """Betm with the section's coefficients and its per-sample residual spreads as variances;
    where the free current law replaced I = C_n |n|^3 + I_0 (`current_exponent` among the
    fits), it carries that law, the one its C_i was fitted with."""
    f = sec.fits

    def v(name: str, fallback: str | None = None) -> float:
        c = f.get(name) or (f.get(fallback) if fallback else None)
        return float(c.value) if c is not None else math.nan

    free = "current_exponent" in f  # the free current law replaced the textbook one
    law = ({"c_n": v("C_free"), "i_0": v("I_0_free"), "current_exponent": v("current_exponent")}
           if free else {"c_n": v("C_n"), "i_0": v("I_0")})
    return Betm(cp_fwd=v("C_p_fwd"), cp_rev=v("C_p_rev", "C_p_fwd"), **law,
                ci_fwd=v("C_i_fwd_direct", "C_i_fwd"),
                ci_rev=v("C_i_rev_direct", "C_i_rev_direct") if "C_i_rev_direct" in f
                else v("C_i_rev", "C_i_fwd_direct"),
                sigma_n=v("sigma_n_sample"), sigma_i=v("sigma_i_sample"),
                voltage_v=math.nan if sec.voltage_v is None else sec.voltage_v, **kw)


def level_variances(betm: Betm, f: np.ndarray, speed_rpm: np.ndarray, current_a: np.ndarray,
                    n_levels: int = 8, min_count: int = 20) -> Betm:
    """`betm` with level-dependent estimator stds from deep residuals (f zero-corrected).

    Residuals are binned by quantiles of |f_n|; each bin's stds come from `split_variances`.
    The current estimate's error grows at low current, where (I - I_0)^(2/3) is steep, so one
    number per estimator would mis-weight the fusion at one end of the range.
    """
    f_n = betm.speed_estimate(speed_rpm)
    f_i = betm.current_estimate(current_a, speed_rpm)
    e_n, e_i = f - f_n, f - f_i
    ok = np.isfinite(e_n) & np.isfinite(e_i)
    s_n, s_i, m = split_variances(e_n[ok], e_i[ok])
    a = np.abs(f_n[ok])
    edges = np.unique(np.quantile(a, np.linspace(0, 1, n_levels + 1)))
    knots, sn, si = [], [], []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        sel = (a >= lo) & (a <= hi)
        if sel.sum() < min_count:
            continue
        b_n, b_i, _ = split_variances(e_n[ok][sel], e_i[ok][sel])
        knots.append(float(np.median(a[sel])))
        sn.append(b_n)
        si.append(b_i)
    return Betm(**{**betm.to_dict(), "sigma_n": s_n, "sigma_i": s_i, "sigma_meas": m,
                   "level_n": tuple(knots), "sigma_n_level": tuple(sn),
                   "sigma_i_level": tuple(si)})


def compare_estimators(betm: Betm, f: np.ndarray, speed_rpm: np.ndarray,
                       current_a: np.ndarray) -> list[EstimatorErrors]:
    """Errors of speed-only, current-only and BETM estimates against measured thrust f."""
    est = betm.fuse(speed_rpm, current_a)
    return [EstimatorErrors.of("speed only (C_p |n| n)", est.f_n - f),
            EstimatorErrors.of("current only (C_i (I - I_0)^(2/3))", est.f_i - f),
            EstimatorErrors.of("BETM (fused)", est.thrust_n - f)]
