"""Steady-window choice and per-point statistics on synthetic points."""

import numpy as np
import pytest

from rigtool.analysis.dataset import Samples
from rigtool.analysis.steady import SettlingCriterion, steady_windows

RATE = 1000.0


def _samples(points: list[dict[str, np.ndarray]]) -> Samples:
    counts = [len(p["thrust_n"]) for p in points]
    offsets = np.concatenate(([0], np.cumsum(counts)))
    cat = {k: np.concatenate([p.get(k, np.full(len(p["thrust_n"]), np.nan)) for p in points])
           for k in ("thrust_n", "speed_rpm", "current_a")}
    t = np.concatenate([i * 10 + np.arange(c) / RATE for i, c in enumerate(counts)])
    point = np.repeat(np.arange(len(points)), counts)
    return Samples(t_s=t, point=point, offsets=offsets, **cat)


def _ar1(rng: np.random.Generator, n: int, rho: float, sd: float) -> np.ndarray:
    e = rng.normal(0, sd * np.sqrt(1 - rho**2), n)
    x = np.empty(n)
    x[0] = rng.normal(0, sd)
    for i in range(1, n):
        x[i] = rho * x[i - 1] + e[i]
    return x


def test_transient_is_cut_and_steady_point_kept_whole():
    rng = np.random.default_rng(0)
    t = np.arange(2000) / RATE
    steady = 10 + rng.normal(0, 0.1, t.size)
    transient = 10 - 8 * np.exp(-t / 0.08) + rng.normal(0, 0.1, t.size)
    w = steady_windows(_samples([{"thrust_n": steady}, {"thrust_n": transient}]))
    assert w.first[0] == 0 and w.n_window[0] == 2000
    assert 0.3 <= w.window_start_s[1] <= 0.7
    thrust = w.channels["thrust_n"]
    assert thrust.mean[1] == pytest.approx(10, abs=0.02)
    # What is left of the transient at the window start is within ~z block standard errors.
    clean_at_start = 8 * np.exp(-w.window_start_s[1] / 0.08)
    assert clean_at_start < 0.1
    assert not w.unsteady.any()


def test_window_keeps_minimum_fraction_and_flags_unsteady():
    t = np.arange(1000) / RATE
    slow = 10 - 5 * np.exp(-t / 0.5)  # still settling at the end
    w = steady_windows(_samples([{"thrust_n": slow}]), SettlingCriterion(min_fraction=0.5))
    assert w.n_window[0] == 500 and w.unsteady[0]


def test_start_is_latest_over_channels():
    rng = np.random.default_rng(1)
    t = np.arange(2000) / RATE
    thrust = 5 + rng.normal(0, 0.05, t.size)
    speed = 1000 - 900 * np.exp(-t / 0.1) + rng.normal(0, 1, t.size)
    w = steady_windows(_samples([{"thrust_n": thrust, "speed_rpm": speed}]))
    assert w.window_start_s[0] > 0.3


def test_standard_error_accounts_for_autocorrelation():
    rng = np.random.default_rng(2)
    rho, sd, n = 0.9, 1.0, 3000
    w = steady_windows(_samples([{"thrust_n": _ar1(rng, n, rho, sd)} for _ in range(20)]))
    se = w.channels["thrust_n"].se
    expected = sd * np.sqrt((1 + rho) / (1 - rho) / n)
    naive = sd / np.sqrt(n)
    assert np.median(se) == pytest.approx(expected, rel=0.25)
    assert np.all(se > 2 * naive)


def test_stats_min_max_std_and_missing_channels():
    x = np.tile([1.0, 3.0], 200)
    w = steady_windows(_samples([{"thrust_n": x, "speed_rpm": x * 100}]))
    thrust, current = w.channels["thrust_n"], w.channels["current_a"]
    assert thrust.mean[0] == pytest.approx(2.0)
    assert thrust.min[0] == 1.0 and thrust.max[0] == 3.0
    assert thrust.std[0] == pytest.approx(1.0, rel=0.01)
    assert thrust.unit == "N" and w.channels["speed_rpm"].unit == "r/min"
    assert np.isnan(current.mean[0]) and not current.measured
    assert thrust.peak[0] == 3.0


def test_short_and_empty_points():
    rng = np.random.default_rng(3)
    short = 1 + rng.normal(0, 0.1, 30)
    w = steady_windows(_samples([{"thrust_n": short}, {"thrust_n": np.zeros(0)}]))
    assert w.n_window[0] == 30 and w.n_window[1] == 0
    assert np.isfinite(w.channels["thrust_n"].se[0])
    assert np.isnan(w.channels["thrust_n"].mean[1])


def test_peak_follows_sign_of_mean():
    x = -2 + np.tile([-0.3, 0.1], 100)
    w = steady_windows(_samples([{"thrust_n": x}]))
    assert w.channels["thrust_n"].peak[0] == pytest.approx(-2.3)
