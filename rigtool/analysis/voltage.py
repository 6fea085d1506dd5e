"""Calibration across supply voltages: C_p, C_n(U) and C_i(U) per voltage, and a fitted
C_n(U) law.

From the power balance I U eta cos(phi) = 2 pi Q n with Q = rho D^5 K_Q n^2, the current
coefficient is C_n = rho D^5 K_Q / (eta U cos phi): inversely proportional to the supply
voltage U, while C_p (thrust per speed squared) does not depend on U at all. So the law
fitted is C_n(U) = k U^b (b = -1 expected), and C_p is checked for consistency across
voltages. U is the voltage the supply was set to (a vehicle: its battery voltage at rest);
the bus sags below it under load, and the mean bus voltage per point set is reported
beside it.
"""

from __future__ import annotations

import math

import numpy as np

from rigtool.analysis.fits import Coefficient, derive_thrust_current, with_systematic, wls
from rigtool.analysis.results import VoltageLaw, VoltagePoint

Z95 = 1.96
CP_DIFFERS_P = 1e-3  # C_p differs between voltages when chance gives its scatter less often
CP_DIFFERS_REL = 0.01  # ... and one voltage's C_p is this far (relative) from the common one


def _se(c: Coefficient) -> float:
    """Standard error from the statistical 95 % interval: the systematic allowance (sensor
    scale) is common to every voltage, so it neither weights nor tests them."""
    lo, hi = c.statistical
    return (hi - lo) / (2 * Z95)


def _usable(c: Coefficient | None) -> bool:
    return c is not None and math.isfinite(c.value) and c.value > 0 and _se(c) > 0


def voltage_point(voltage_v: float, bus_v: float, fits: dict[str, Coefficient]) -> VoltagePoint:
    """One voltage's coefficients from its section's fits; C_i derived where not given."""
    cp_fwd, cp_rev, cn = fits.get("C_p_fwd"), fits.get("C_p_rev"), fits.get("C_n")
    ci_fwd, ci_rev = fits.get("C_i_fwd"), fits.get("C_i_rev")
    if ci_fwd is None and _usable(cp_fwd) and _usable(cn):
        ci_fwd = derive_thrust_current(cp_fwd, cn, "C_i_fwd")
    if ci_rev is None and _usable(cp_rev) and _usable(cn):
        ci_rev = derive_thrust_current(cp_rev, cn, "C_i_rev")
    k = fits["current_exponent"].value if "current_exponent" in fits else 3.0
    return VoltagePoint(voltage_v, bus_v, cp_fwd, cp_rev, cn, ci_fwd, ci_rev, k)


def fit_voltage_law(depth_m: float | None, points: list[VoltagePoint]) -> VoltageLaw | None:
    """Fit log C_n = log k + b log U, weighted by each C_n's interval; None with fewer than
    two voltages that have a C_n (a line through two points has no scatter to judge it by)."""
    use = [p for p in points if _usable(p.cn)]
    if len(use) < 2:
        return None
    u = np.array([p.voltage_v for p in use])
    cn = np.array([p.cn.value for p in use])
    sigma = np.array([_se(p.cn) / p.cn.value for p in use])  # of log C_n
    design = np.column_stack([np.ones(u.size), np.log(u)])
    fit = wls(design, np.log(cn), sigma)
    n = len(use)
    log_k, b = fit.beta
    hw_k, hw_b = fit.half_width(0), fit.half_width(1)
    note = f"C_n(U) = k U^b over {n} voltages"
    k = Coefficient("C_n_law_k", math.exp(log_k), math.exp(log_k - hw_k), math.exp(log_k + hw_k),
                    "A/(r/min)^3 V^-b", n, note=note)
    b_coef = Coefficient("C_n_law_b", float(b), float(b - hw_b), float(b + hw_b), "1", n,
                         note=note + "; -1 expected (C_n proportional to 1/U)")
    # b fixed at -1: log(C_n U) = log k, a weighted mean
    inv = wls(np.ones((n, 1)), np.log(cn * u), sigma)
    hw = inv.half_width(0) if n > 1 else math.nan
    k_inv = Coefficient("C_n_law_k_inverse", math.exp(inv.beta[0]), math.exp(inv.beta[0] - hw),
                        math.exp(inv.beta[0] + hw), "A V/(r/min)^3", n,
                        note="C_n(U) = k / U: the physical law, b fixed at -1")
    rel = max(p.cn.systematic / p.cn.value for p in use)
    k, k_inv = with_systematic(k, rel), with_systematic(k_inv, rel)
    warnings = []
    if not b_coef.lo <= -1.0 <= b_coef.hi:
        warnings.append(f"C_n(U) exponent b = {b:.3f} ({b_coef.lo:.3f} .. {b_coef.hi:.3f}) "
                        "excludes -1: the current does not scale as 1/U (a speed loop, current "
                        "limiting, or a voltage the driver regulates)")
    chi2, consistent = _cp_consistency([p.cp_fwd for p in points])
    if not consistent:
        warnings.append(f"C_p_fwd differs between supply voltages beyond its intervals "
                        f"(reduced chi-square {chi2:.2f}, by {CP_DIFFERS_REL:.0%} or more); "
                        "C_p should not depend on U: check for ventilation, a sensor zero that "
                        "moved, or a limit that cut points")
    return VoltageLaw(depth_m, points, k, b_coef, k_inv, chi2, consistent, warnings)


def _cp_consistency(cps: list[Coefficient | None]) -> tuple[float, bool]:
    """Reduced chi-square of the C_p values about their weighted mean, and whether they agree:
    C_p differs only when chance would give that scatter less than CP_DIFFERS_P of the time
    and a voltage's C_p is at least CP_DIFFERS_REL from the common value (a 5 % test on six
    voltages cries wolf in one table of four when the intervals are a little narrow, and a
    difference far below 1 % is no sign of ventilation or a moved zero)."""
    use = [c for c in cps if _usable(c)]
    if len(use) < 2:
        return math.nan, True
    v = np.array([c.value for c in use])
    w = 1.0 / np.array([_se(c) for c in use]) ** 2
    mean = float(np.sum(w * v) / np.sum(w))
    dof = len(use) - 1
    chi2 = float(np.sum(w * (v - mean) ** 2))
    from scipy import special  # not scipy.stats: 0.6 s more to import

    significant = special.chdtrc(dof, chi2) < CP_DIFFERS_P
    material = float(np.max(np.abs(v / mean - 1))) >= CP_DIFFERS_REL
    return chi2 / dof, not (significant and material)
