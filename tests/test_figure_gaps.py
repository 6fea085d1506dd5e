"""Time-series figures of the report draw nothing where there are no data: every line and band
breaks at the rests and depth moves between points, and at samples lost inside a point."""

from __future__ import annotations

import types

import numpy as np
import pytest
from matplotlib.collections import PolyCollection
from matplotlib.figure import Figure

from rigtool.report import figures as fg
from rigtool.report.cavitation import time_series_figure


def _segments(rng: np.random.Generator, n_points: int, step_s: float
              ) -> tuple[np.ndarray, np.ndarray, list[tuple[float, float]]]:
    """Sample times of `n_points` points separated by random rests; the point of each sample,
    and the gaps (end of one point, start of the next)."""
    t, point, gaps, now = [], [], [], 3.0
    for k in range(n_points):
        n = int(rng.integers(20, 60))
        t.append(now + step_s * np.arange(n))
        point.append(np.full(n, k))
        now = float(t[-1][-1]) + rng.uniform(4.0, 30.0)
        if k < n_points - 1:
            gaps.append((float(t[-1][-1]), now))
    return np.concatenate(t), np.concatenate(point), gaps


def _runs(x: np.ndarray) -> list[tuple[float, float]]:
    """(first, last) x of each stretch a line joins: finite values between NaNs."""
    out, start = [], None
    for i, v in enumerate(np.append(np.asarray(x, dtype=float), np.nan)):
        if np.isfinite(v) and start is None:
            start = i
        elif not np.isfinite(v) and start is not None:
            out.append((float(np.min(x[start:i])), float(np.max(x[start:i]))))
            start = None
    return out


def _drawn_across(fig: Figure, gaps: list[tuple[float, float]]) -> list[str]:
    """Data lines (with a line style) and bands of `fig` that span one of `gaps`; a window's
    mean level is a statistic, not data, and may cross a gap inside the window."""
    bad = []
    for ax in fig.axes:
        for line in ax.get_lines():
            if line.get_linestyle() in ("None", "", " ") or line.get_label() == "window mean":
                continue
            spans = _runs(np.asarray(line.get_xdata(), dtype=float))
            bad += [f"line {line.get_label()}" for lo, hi in spans for a, b in gaps
                    if lo <= a and hi >= b]
        for coll in ax.collections:
            if not isinstance(coll, PolyCollection):
                continue
            for path in coll.get_paths():
                x = path.vertices[:, 0]
                bad += [f"band {coll.get_label()}" for a, b in gaps
                        if x.min() <= a and x.max() >= b]
    return bad


@pytest.mark.parametrize("seed", [3, 8])
def test_quasi_cavitation_band_breaks_between_points(seed):
    rng = np.random.default_rng(seed)
    t, point, gaps = _segments(rng, 4, 0.5)
    f = 30 + 10 * np.sin(t / 7) + rng.normal(0, 1, t.size)
    series = {"t_s": t, "thrust_n": f, "betm_n": f + 1, "pred_n": f - 0.5,
              "lo95_n": f - 3, "hi95_n": f + 3, "point": point}
    fig = time_series_figure(types.SimpleNamespace(series=series, events=[]))
    assert _drawn_across(fig, gaps) == []
    bands = [c for c in fig.axes[0].collections if isinstance(c, PolyCollection)]
    assert sum(len(c.get_paths()) for c in bands) == len(gaps) + 1


def test_point_trace_breaks_where_samples_were_lost():
    rng = np.random.default_rng(21)
    t = np.arange(3000) / 1000.0
    lost = (t > 1.2) & (t < 1.45)
    t, y = t[~lost], 20 + rng.normal(0, 0.2, int((~lost).sum()))
    trace = fg.Trace("point 3", t, y, 0.5, float(y.mean()))
    fig = fg.time_series([trace])
    assert _drawn_across(fig, [(1.2, 1.45)]) == []
    samples = [ln for ln in fig.axes[0].get_lines() if ln.get_label() == "thrust samples"]
    assert len(_runs(samples[0].get_xdata())) == 2


def test_step_response_lines_break_between_points():
    rng = np.random.default_rng(5)
    t, _, gaps = _segments(rng, 5, 0.002)
    measured = rng.normal(0, 1, t.size)
    fig = fg.step_responses(t, measured, {"one-state": measured * 0.9}, np.array([t[0]]))
    assert _drawn_across(fig, gaps) == []


def test_long_traces_are_still_decimated_and_broken():
    rng = np.random.default_rng(9)
    t, _, gaps = _segments(rng, 3, 0.001)
    t = np.concatenate([t, t[-1] + 40 + 0.001 * np.arange(30_000)])
    gaps.append((float(t[-30_001]), float(t[-30_000])))
    x, y = fg._decimate(t, rng.normal(0, 1, t.size), 2000)
    assert x.size <= 2000 + 2 * len(gaps) + 8
    assert len(_runs(x)) == len(gaps) + 1
