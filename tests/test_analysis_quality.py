"""Hysteresis, repeatability and tare drift."""

import numpy as np
import pytest

from rigtool.analysis.quality import hysteresis, repeatability, tare_drift


def test_hysteresis_up_minus_down():
    cmd = np.array([0.0, 10, 20, 20, 10, 0])
    direction = np.array(["up", "up", "up", "down", "down", "down"])
    mean = np.array([0.0, 1.0, 2.0, 2.0, 0.7, 0.1])
    h = hysteresis(cmd, direction, mean, np.full(6, 0.03))
    assert list(h.command) == [0, 10, 20]
    assert h.diff_n == pytest.approx([-0.1, 0.3, 0.0])
    assert h.max_abs_n == pytest.approx(0.3) and h.at_command == 10
    assert h.diff_se_n == pytest.approx(np.full(3, 0.03 * np.sqrt(2)))


def test_hysteresis_needs_both_directions():
    assert hysteresis(np.arange(3.0), np.array(["up"] * 3), np.ones(3), np.ones(3)) is None


def test_repeatability_per_command_and_direction():
    cmd = np.array([1.0, 1, 1, 2, 2, 2, 1])
    direction = np.array(["up"] * 6 + ["down"])
    rep = np.array([0, 1, 2, 0, 1, 2, 0])
    mean = np.array([1.0, 1.2, 1.4, 3.0, 3.0, 3.0, 9.0])
    r = repeatability(cmd, direction, rep, mean)
    assert list(r.command) == [1, 2] and list(r.direction) == ["up", "up"]
    assert list(r.n_repeats) == [3, 3]
    assert r.std_n == pytest.approx([0.2, 0.0])
    assert r.max_std_n == pytest.approx(0.2)
    assert repeatability(cmd, direction, np.zeros(7, int), mean) is None


def test_tare_drift_slope_in_newton_per_hour():
    rng = np.random.default_rng(0)
    t = np.arange(0.0, 7200.0, 600.0)
    bias = 0.3 + 0.05 * t / 3600 + rng.normal(0, 0.002, t.size)
    d = tare_drift(t, bias)
    assert d.slope.unit == "N/h" and d.slope.n == t.size
    assert d.slope.value == pytest.approx(0.05, abs=0.005)
    assert d.slope.lo < 0.05 < d.slope.hi
    assert d.bias_n[0] == 0.0  # relative to the first tare
    assert d.zero_scatter_n == pytest.approx(0.05 / 6, abs=0.004)


def test_tare_drift_needs_two_tares():
    assert tare_drift(np.array([1.0]), np.array([0.2])) is None
    assert tare_drift(np.array([1.0, 2.0]), None) is None
    two = tare_drift(np.array([0.0, 3600.0]), np.array([0.0, 0.1]))
    assert two.slope.value == pytest.approx(0.1) and np.isnan(two.slope.lo)
