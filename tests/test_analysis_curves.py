"""Command curves: dead zones, saturation, break-aways, branches, inverse LUT."""

import numpy as np
import pytest

from rigtool.analysis.curves import CurveParams, aggregate, command_curve, find_dead, ranges


def stm32_thrust(pwm: np.ndarray) -> np.ndarray:
    """The STM32 bench rig map of domain.md 1B (forward branch inverted, break-away at 451)."""
    f = np.zeros_like(pwm)
    f = np.where((pwm >= 207) & (pwm <= 396), 5.0 - 0.0005 * (pwm - 207), f)
    f = np.where((pwm >= 397) & (pwm <= 427), 4.9 + (0.15 - 4.9) * (pwm - 397) / 30, f)
    f = np.where((pwm >= 446) & (pwm <= 450), -0.1, f)
    f = np.where((pwm >= 451) & (pwm <= 470), -1.0 - 2.0 * (pwm - 451) / 19, f)
    return np.where(pwm > 470, -3.0 - 0.0003 * (pwm - 470), f)


def _curve(cmd, mean, se, unit="pwm_counts", neutral=0.0, **kw):
    """One point per command, swept in command order at one point per second."""
    nan = np.full(cmd.size, np.nan)
    t = np.arange(cmd.size, dtype=float)
    return command_curve(cmd, t, mean, se, mean - 3 * se, mean + 3 * se, nan, nan,
                         command_unit=unit, neutral_command=neutral, **kw)


def _stm32(seed: int = 0):
    rng = np.random.default_rng(seed)
    pwm = np.arange(800.0)
    f = stm32_thrust(pwm)
    se = np.where(f > 0, 0.08, 0.015) / np.sqrt(500) * 2  # per-sample sd over 500 samples
    zero_offset = rng.normal(0, 0.004, pwm.size)  # residual tare drift
    return pwm, f + rng.normal(0, 1, pwm.size) * se + zero_offset, se


def test_stm32_dead_zones_branches_break_away():
    pwm, mean, se = _stm32()
    c = _curve(pwm, mean, se)
    (lo1, hi1), (lo2, hi2) = c.dead_zones
    assert abs(lo1 - 0) <= 2 and abs(hi1 - 206) <= 2
    assert abs(lo2 - 428) <= 2 and abs(hi2 - 445) <= 2
    assert c.break_aways == [451.0]
    # 427 (+0.15 N) and 446-450 (-0.1 N) are live.
    live = c.state[np.isin(c.command, [427, 446, 447, 448, 449, 450])]
    assert np.all(live != "dead")
    fwd, rev = c.branches
    assert fwd.direction == "forward" and fwd.inverted and fwd.slope_sign == -1
    assert rev.direction == "reverse" and not rev.inverted and rev.slope_sign == -1
    assert fwd.saturated[0] == 207 and abs(fwd.saturated[1] - 396) <= 3
    assert abs(rev.saturated[0] - 470) <= 3 and rev.saturated[1] == 799
    assert c.saturated == [fwd.saturated, rev.saturated]


def test_lut_covers_usable_range_only_and_inverts_the_fit():
    pwm, mean, se = _stm32(1)
    c = _curve(pwm, mean, se)
    thrust, command, branch = c.lut
    assert not c.is_dead(command).any()
    for i, b in enumerate(c.branches):
        f, u = thrust[branch == i], command[branch == i]
        assert np.all(np.diff(f) > 0)
        assert u.min() >= b.usable[0] and u.max() <= b.usable[1]
        assert not ((u >= b.saturated[0]) & (u <= b.saturated[1])).any()
    fwd_f, fwd_u = thrust[branch == 0], command[branch == 0]
    # 2.5 N lies half-way down the 397-427 ramp.
    assert np.interp(2.5, fwd_f, fwd_u) == pytest.approx(397 + 30 * (4.9 - 2.5) / 4.75, abs=1.0)


def test_esc_deadband():
    rng = np.random.default_rng(2)
    us = np.arange(1100.0, 1901.0, 4.0)
    x = np.where(us > 1525, (us - 1525) / 375, np.where(us < 1475, (us - 1475) / 375, 0))
    f = np.where(x > 0, 40 * x**2 + 0.3, np.where(x < 0, -32 * x**2 - 0.3, 0))
    se = np.full(us.size, 0.01)
    c = _curve(us, f + rng.normal(0, 0.01, us.size), se, unit="pulse_us", neutral=1500.0)
    ((lo, hi),) = c.dead_zones
    assert abs(lo - 1475) <= 4 and abs(hi - 1525) <= 4
    assert [b.direction for b in c.branches] == ["reverse", "forward"]
    assert not any(b.inverted for b in c.branches)
    assert c.break_aways == [] and c.saturated == []


def test_no_dead_zone():
    cmd = np.arange(10.0, 101.0, 5.0)
    f = 0.004 * cmd**2
    c = _curve(cmd, f, np.full(cmd.size, 0.01), unit="percent")
    assert c.dead_zones == [] and len(c.branches) == 1
    assert c.saturated == [] and c.break_aways == []


def test_one_sided_dead_zone_and_saturation():
    cmd = np.arange(0.0, 101.0, 1.0)
    f = np.clip(0.1 * (cmd - 20), 0, 6.0)
    f[cmd <= 20] = 0.0
    c = _curve(cmd, f, np.full(cmd.size, 0.005), unit="percent")
    assert c.dead_zones == [(0.0, 20.0)]
    (b,) = c.branches
    assert b.direction == "forward" and not b.inverted
    assert b.saturated[1] == 100 and abs(b.saturated[0] - 80) <= 3


def test_noisy_dead_zone_with_honest_errors():
    rng = np.random.default_rng(4)
    cmd = np.arange(-50.0, 51.0, 1.0)
    f = np.where(np.abs(cmd) > 10, np.sign(cmd) * 0.05 * np.clip(np.abs(cmd) - 10, 0, None) ** 1.5, 0.0)
    se = np.full(cmd.size, 0.3)
    c = _curve(cmd, f + rng.normal(0, 0.3, cmd.size), se, unit="percent")
    ((lo, hi),) = c.dead_zones
    # Noise widens the zone to where thrust exceeds ~4 SE (1.2 N at |cmd| ~ 18), never splits it.
    assert -22 <= lo <= -10 and 10 <= hi <= 22


def test_isolated_marginal_point_is_merged_into_dead_zone():
    cmd = np.arange(0.0, 30.0)
    f = np.where(cmd >= 20, 0.5 * (cmd - 19), 0.0)
    f[10] = 0.03  # just above the 0.02 N floor
    dead = find_dead(f, np.full(cmd.size, 0.001), 0.02, CurveParams())
    assert ranges(cmd, dead) == [(0.0, 19.0)]


def test_zero_drift_is_removed_before_the_dead_zone_test():
    """Tared at the start, the zero drifts 0.05 N over the sweep: 428-445 must still be dead."""
    pwm, mean, se = _stm32(3)
    drifting = _curve(pwm, mean + 0.05 * pwm / 800, se)
    assert drifting.dead_zones == _curve(pwm, mean, se).dead_zones
    assert abs(drifting.dead_zones[1][0] - 428) <= 2
    assert drifting.zero.source == "dead zones"
    assert drifting.zero.at(np.array([400.0]))[0] == pytest.approx(0.025, abs=0.005)


def test_floor_follows_zero_scatter_and_tares():
    cmd = np.arange(0.0, 40.0)
    f = np.where(cmd >= 30, 1.0 * (cmd - 29), 0.0)
    f[:30] = 0.01 * np.sin(3 * cmd[:30])  # the zero wanders by +-0.01 N, SEs say 0.001 N
    se = np.full(cmd.size, 0.001)
    c = _curve(cmd, f, se)
    assert c.dead_zones == [(0.0, 29.0)] and c.floor_n > 0.01
    tared = _curve(cmd, f, se, zero_scatter_n=0.05)
    assert tared.floor_n == pytest.approx(0.15)


def test_inverted_reverse_branch_and_sign_split():
    cmd = np.arange(0.0, 41.0)
    # A speed-controlled style curve crossing zero without a dead point: two branches.
    f = 0.2 * (cmd - 20.5) * np.abs(cmd - 20.5)
    c = _curve(cmd, f, np.full(cmd.size, 0.001), unit="percent", neutral=20.5)
    assert c.dead_zones == []
    assert [b.direction for b in c.branches] == ["reverse", "forward"]
    assert not any(b.inverted for b in c.branches)
    # |thrust| largest next to neutral, falling away from it: both branches inverted.
    g = np.sign(cmd - 20.5) * (0.5 + 0.2 * (20.5 - np.abs(cmd - 20.5)))
    inverted = _curve(cmd, g, np.full(cmd.size, 0.001), unit="percent", neutral=20.5)
    assert len(inverted.branches) == 2 and all(b.inverted for b in inverted.branches)


def test_aggregate_pools_repeats():
    cmd = np.array([1.0, 1.0, 2.0, 2.0])
    mean = np.array([1.0, 1.2, 2.0, 2.0])
    se = np.full(4, 0.01)
    c, k, m, s, lo, hi = aggregate(cmd, mean, se, mean - 1, mean + 1)
    assert list(c) == [1, 2] and list(k) == [2, 2]
    assert m == pytest.approx([1.1, 2.0])
    assert s[0] == pytest.approx(0.1)  # repeat scatter dominates the 0.007 N propagated SE
    assert s[1] == pytest.approx(0.01 / np.sqrt(2))
    assert lo[0] == 0.0 and hi[0] == pytest.approx(2.2)
