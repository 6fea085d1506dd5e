"""Model fits on synthetic data with known coefficients."""

import math

import numpy as np
import pytest

from rigtool.analysis.fits import (
    _ar1_correlate,
    derive_thrust_current,
    fit_current_exponent,
    fit_current_speed,
    fit_thrust_current,
    fit_thrust_speed,
    residual_spread,
    thrust_coefficient,
    wls,
)

CP, CN, I0 = 1.926e-5, 1.2e-9, 0.3
UNIT = "N/(r/min)^2"


def _speeds(sign: float = 1.0) -> np.ndarray:
    return sign * np.linspace(150.0, 1800.0, 40)


def _thrust_fit(n, f, se, se_n=None, t=None):
    """Joint C_p fit; points are taken one per second in the given order unless `t`."""
    t = np.arange(n.size, dtype=float) if t is None else t
    return fit_thrust_speed(n, f, se, se_n, t, {"fwd": n > 0, "rev": n < 0})


def _cp(n, f, se, **kw):
    fit = _thrust_fit(n, f, se, **kw)
    key = "fwd" if n[0] > 0 else "rev"
    return fit.coefficient(key, f"C_p_{key}", UNIT, "")


def test_thrust_speed_recovers_cp_within_interval():
    rng = np.random.default_rng(0)
    n = _speeds()
    se = np.full(n.size, 0.05)
    f = CP * n**2 + rng.normal(0, 0.05, n.size)
    fit = _thrust_fit(n, f, se, np.full(n.size, 0.5))
    c = fit.coefficient("fwd", "C_p_fwd", UNIT, "")
    assert abs(c.value / CP - 1) < 0.01
    assert c.lo < CP < c.hi
    assert c.unit == UNIT and c.n == 40 and c.r2 > 0.999
    assert c.rms == pytest.approx(0.05, rel=0.3)
    offset, drift = fit.zero_coefficients()
    assert offset.name == "f_0" and offset.unit == "N" and offset.lo < 0 < offset.hi
    assert drift.name == "zero_drift" and drift.unit == "N/h" and drift.lo < 0 < drift.hi


def test_reverse_fit_uses_signed_model():
    rng = np.random.default_rng(1)
    n = _speeds(-1.0)
    f = -0.8 * CP * n**2 + rng.normal(0, 0.05, n.size)
    assert _cp(n, f, np.full(n.size, 0.05)).value == pytest.approx(0.8 * CP, rel=0.01)


def test_both_directions_share_the_zero():
    rng = np.random.default_rng(1)
    n = np.concatenate([_speeds(-1.0)[::-1], _speeds()])  # an up sweep: reverse first
    t = np.arange(n.size) * 10.0
    zero = 0.3 + 0.6 * t / 3600  # tared offset 0.3 N, drifting 0.6 N/h
    f = np.where(n > 0, CP, 0.8 * CP) * np.abs(n) * n + zero + rng.normal(0, 0.02, n.size)
    fit = _thrust_fit(n, f, np.full(n.size, 0.02), t=t)
    fwd = fit.coefficient("fwd", "C_p_fwd", UNIT, "")
    rev = fit.coefficient("rev", "C_p_rev", UNIT, "")
    assert fwd.lo < CP < fwd.hi and rev.lo < 0.8 * CP < rev.hi
    assert fwd.n == rev.n == 40
    drift = fit.zero_coefficients()[1]
    assert drift.lo < 0.6 < drift.hi and drift.value == pytest.approx(0.6, rel=0.2)
    assert fit.zero.at(t) == pytest.approx(zero, abs=0.02)


def test_serial_correlation_widens_interval():
    """A slow wander of the zero shared by neighbouring points must widen the interval."""
    n = _speeds()
    t = np.arange(n.size, dtype=float)
    hits = 0
    for seed in range(100):
        rng = np.random.default_rng(seed)
        wander = 0.2 * np.sin(2 * np.pi * t / rng.uniform(8, 25) + rng.uniform(0, 6))
        f = CP * n**2 + wander + rng.normal(0, 0.01, n.size)
        c = _cp(n, f, np.full(n.size, 0.01), t=t)
        hits += c.lo < CP < c.hi
    assert hits >= 88


@pytest.mark.parametrize("n", [1, 2, 9, 300])
@pytest.mark.parametrize("r1", [0.0, 0.4, 0.98])
def test_ar1_correlation_product_matches_the_dense_matrix(n, r1):
    a = np.random.default_rng(n).normal(size=(n, 3))
    dense = r1 ** np.abs(np.subtract.outer(np.arange(n), np.arange(n)))
    np.testing.assert_allclose(_ar1_correlate(a, r1), dense @ a, rtol=1e-10, atol=1e-12)


def test_interval_is_honest_when_scatter_exceeds_standard_errors():
    """Point SEs claim 0.01 N but the means scatter by 0.2 N: ~95 % coverage anyway."""
    n = _speeds()
    hits = 0
    trials = 200
    for seed in range(trials):
        rng = np.random.default_rng(seed)
        f = CP * n**2 + rng.normal(0, 0.2, n.size)
        c = _cp(n, f, np.full(n.size, 0.01), t=rng.permutation(n.size).astype(float))
        hits += c.lo < CP < c.hi
    assert 0.90 <= hits / trials <= 0.99


def test_wls_scales_covariance_only_when_chi2_exceeds_one():
    x = np.linspace(1, 10, 20)[:, None]
    y = 2 * x[:, 0]
    tight = wls(x, y + np.tile([0.001, -0.001], 10), np.full(20, 1.0))
    assert tight.chi2_red < 1
    assert math.sqrt(tight.cov[0, 0]) == pytest.approx(1 / math.sqrt(np.sum(x**2)))


def test_current_cubic_fit_and_free_exponent():
    rng = np.random.default_rng(2)
    n = np.concatenate([_speeds(), _speeds(-1.0)])
    se = np.full(n.size, 0.02)
    cur = CN * np.abs(n) ** 3 + I0 + rng.normal(0, 0.02, n.size)
    c_n, i_0, _ = fit_current_speed(n, cur, se, None)
    assert abs(c_n.value / CN - 1) < 0.03 and c_n.lo < CN < c_n.hi
    assert i_0.value == pytest.approx(I0, abs=0.02) and i_0.lo < I0 < i_0.hi
    assert i_0.hi > i_0.lo
    k, c, i0 = fit_current_exponent(n, cur, se, c_n.value, i_0.value)
    assert k.name == "k_free" and k.lo < 3 < k.hi and abs(k.value - 3) < 0.05
    assert c.value == pytest.approx(CN, rel=0.2) and c.lo < c.value < c.hi
    assert i0.value == pytest.approx(I0, abs=0.03)


def test_free_exponent_finds_other_exponent():
    n = _speeds()
    cur = 2e-7 * n**2.5 + 0.5
    k, _, _ = fit_current_exponent(n, cur, np.full(n.size, 0.01), 1e-9, 0.4)
    assert k.value == pytest.approx(2.5, abs=1e-3)


def test_thrust_from_current_derived_and_direct_agree():
    n = np.concatenate([_speeds(-1.0), _speeds()])
    f = np.where(n > 0, 1.0, 0.8) * CP * np.abs(n) * n
    cur = CN * np.abs(n) ** 3 + I0
    se_f, se_i = np.full(n.size, 0.05), np.full(n.size, 0.01)
    cp = _cp(n[40:], f[40:], se_f[40:])
    c_n, i_0, _ = fit_current_speed(n, cur, se_i, None)
    derived = derive_thrust_current(cp, c_n, "C_i_fwd")
    assert derived.value == pytest.approx(CP / CN ** (2 / 3), rel=1e-6)
    assert derived.unit == "N/A^(2/3)" and derived.lo <= derived.value <= derived.hi
    masks = {"fwd": n > 0, "rev": n < 0}
    direct = fit_thrust_current(cur, i_0.value, f, se_f, se_i, np.arange(n.size, dtype=float),
                                masks)
    fwd = direct.coefficient("fwd", "C_i_fwd_direct", "N/A^(2/3)", "")
    rev = direct.coefficient("rev", "C_i_rev_direct", "N/A^(2/3)", "")
    assert fwd.value == pytest.approx(derived.value, rel=1e-3)
    assert rev.value == pytest.approx(0.8 * derived.value, rel=1e-3)


def test_derived_interval_propagates_relative_errors():
    from rigtool.analysis.fits import Coefficient

    cp = Coefficient("C_p", 2.0, 1.9, 2.1, "N/(r/min)^2")  # 5 %
    cn = Coefficient("C_n", 8.0, 7.4, 8.6, "A/(r/min)^3")  # 7.5 %
    ci = derive_thrust_current(cp, cn, "C_i")
    assert ci.value == pytest.approx(0.5)
    assert (ci.hi - ci.lo) / 2 / ci.value == pytest.approx(math.hypot(0.05, 0.05))


def test_kt_from_cp():
    from rigtool.analysis.fits import Coefficient

    cp = Coefficient("C_p_fwd", CP, CP * 0.99, CP * 1.01, "N/(r/min)^2", 10, 0.999, 0.1, "N")
    kt = thrust_coefficient(cp, 0.1, 1000.0, "K_T_fwd")
    # f = K_T rho n^2 D^4 with n in rev/s: at 1404 r/min, 23.4 rev/s.
    n_rps = 1404 / 60
    assert kt.value * 1000.0 * n_rps**2 * 0.1**4 == pytest.approx(CP * 1404**2)
    assert kt.unit == "1" and kt.lo < kt.value < kt.hi


def test_residual_spread():
    rng = np.random.default_rng(3)
    r = rng.normal(0, 0.5, 400)
    s = residual_spread(r, "sigma_n_point", "", interval=True)
    assert s.value == pytest.approx(0.5, rel=0.1) and s.lo < 0.5 < s.hi and s.unit == "N"
    s = residual_spread(r, "sigma_n_sample", "", interval=False)
    assert math.isnan(s.lo) and math.isnan(s.hi)


def test_derived_interval_uses_the_correlation():
    from rigtool.analysis.fits import Coefficient

    cp = Coefficient("C_p", 2.0, 1.9, 2.1, "N/(r/min)^2")  # 5 %
    cn = Coefficient("C_n", 8.0, 6.8, 9.2, "A/(r/min)^3")  # 15 % -> 10 % after the power 2/3
    independent = derive_thrust_current(cp, cn, "C_i")
    shared = derive_thrust_current(cp, cn, "C_i", rho=0.9)
    assert (independent.hi - independent.lo) / 2 == pytest.approx(0.5 * math.hypot(0.05, 0.1))
    assert (shared.hi - shared.lo) / 2 == pytest.approx(
        0.5 * math.sqrt(0.05**2 + 0.1**2 - 2 * 0.9 * 0.05 * 0.1))


def test_derived_c_i_interval_covers_truth_when_speed_errors_are_shared():
    """Speed read with a per-point error moves C_p and C_n together: the derived C_i interval,
    with their estimated correlation, covers the truth at about its stated rate and is
    narrower than the one that treats them as independent."""
    from rigtool.analysis.fits import coefficient_correlation

    rng = np.random.default_rng(321)
    n_true = np.linspace(300.0, 1800.0, 60)
    truth = CP / CN ** (2 / 3)
    hits, ratio = 0, []
    for _ in range(300):
        n = n_true + rng.normal(0, 4.0, n_true.size)  # the measured mean speed of each point
        f = CP * n_true**2 + rng.normal(0, 0.02, n_true.size)
        cur = CN * n_true**3 + I0 + rng.normal(0, 0.002, n_true.size)
        t = np.arange(n_true.size, dtype=float)
        thrust = fit_thrust_speed(n, f, np.full(n.size, 0.02), None, t, {"fwd": n > 0})
        c_n, _, cn_fit = fit_current_speed(n, cur, np.full(n.size, 0.002), None)
        cp = thrust.coefficient("fwd", "C_p_fwd", "", "")
        rows = np.arange(n.size)
        rho = coefficient_correlation(thrust.fit, 0, rows, cn_fit, 0, rows)
        ci = derive_thrust_current(cp, c_n, "C_i", rho)
        plain = derive_thrust_current(cp, c_n, "C_i")
        hits += ci.lo <= truth <= ci.hi
        ratio.append((ci.hi - ci.lo) / (plain.hi - plain.lo))
    assert 0.90 <= hits / 300 <= 0.99
    assert np.median(ratio) < 0.95
