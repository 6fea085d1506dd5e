"""Calibrate's passes over a run's samples, block of points by block, never the whole run.

The first pass chooses every point's steady window and reduces the window to the point
table's statistics, and keeps the strided values the printed-step check looks at; a point
longer than a block is read in pieces and reduced by passes of its own (long_point.py). The
second runs once the fits are known: the per-sample residual spreads (sigma_*_sample) the
fits asked for, summed point block by point block. Memory is bounded by a block,
whatever the length of a point.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from rigtool.analysis.dataset import SAMPLE_FIELDS, PointBlock, RunData
from rigtool.analysis.fits import Coefficient, residual_spread
from rigtool.analysis.long_point import long_point_windows
from rigtool.analysis.steady import (
    RESOLUTION_CHANNELS,
    RESOLUTION_SAMPLES,
    PointTable,
    SettlingCriterion,
    SteadyWindows,
    concat_windows,
    printed_step,
    resolution_stride,
    steady_windows,
)

SPREAD_FIELDS = ("thrust_n", "speed_rpm", "current_a")  # what sample residuals are made of
# residual(point, thrust_n, speed_rpm, current_a) -> the residuals of the samples in the fit
Residual = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], np.ndarray]


def point_pass(run: RunData, criterion: SettlingCriterion) -> tuple[SteadyWindows, PointTable]:
    """Steady windows and the point table of `run`, read one block of points at a time."""
    strides = _Strided(run.source.sample_count())
    parts, counts = [], []
    for block in run.source.blocks((*SAMPLE_FIELDS, "torque_nm", "command")):
        strides.add(block.samples)
        if block.piece:  # a long point: its own passes over its pieces, once all are seen
            if block.last_piece:
                parts.append(long_point_windows(run.source, block.first_row, criterion))
                counts.append(np.array([block.point_n]))
            continue
        windows = steady_windows(block.samples, criterion)
        windows.in_window = windows.in_window[:0]  # per sample: not kept past its block
        parts.append(windows)
        counts.append(np.diff(block.samples.offsets))
    windows = concat_windows(parts)
    table = windows.point_table(run.steps, np.concatenate(counts),
                                strides.resolutions(run))
    return windows, table


class _Strided:
    """The values `steady.printed_step` is handed, gathered block by block: every k-th finite
    value with k from the run's sample count (right when the channel has no NaN), and all
    of them while there are few. A channel with NaNs and many values is read again."""

    def __init__(self, n_total: int) -> None:
        self.stride = resolution_stride(n_total)
        self.n_total = n_total
        self.seen = dict.fromkeys(RESOLUTION_CHANNELS, 0)
        self.picked: dict[str, list[np.ndarray]] = {c: [] for c in RESOLUTION_CHANNELS}
        self.all: dict[str, list[np.ndarray]] = {c: [] for c in RESOLUTION_CHANNELS}

    def add(self, samples) -> None:
        for name in RESOLUTION_CHANNELS:
            x = getattr(samples, name)
            if x is None:
                continue
            v = x[np.isfinite(x)]
            start = (-self.seen[name]) % self.stride
            self.picked[name].append(v[start::self.stride].copy())  # not a view of the block
            if self.seen[name] <= RESOLUTION_SAMPLES:
                self.all[name].append(v)
            self.seen[name] += v.size

    def resolutions(self, run: RunData) -> dict[str, float]:
        out = {}
        for name in RESOLUTION_CHANNELS:
            n = self.seen[name]
            if n <= RESOLUTION_SAMPLES:
                v = np.concatenate(self.all[name]) if self.all[name] else np.empty(0)
            elif resolution_stride(n) == self.stride:
                v = np.concatenate(self.picked[name])
            else:
                v = _strided_again(run, name, resolution_stride(n))
            out[name] = printed_step(v)
        return out


def _strided_again(run: RunData, name: str, stride: int) -> np.ndarray:
    """Every `stride`-th finite value of one channel, read again from the store."""
    seen, picked = 0, []
    for block in run.source.blocks((name,)):
        x = getattr(block.samples, name)
        v = x[np.isfinite(x)]
        picked.append(v[(-seen) % stride::stride].copy())
        seen += v.size
    return np.concatenate(picked) if picked else np.empty(0)


@dataclass
class _Request:
    placeholder: Coefficient
    name: str
    note: str
    residual: Residual
    sum_sq: float = 0.0
    n: int = 0


@dataclass
class SectionSamples:
    """The steady-window samples of one section (`rows`: its steps rows), as the fits see
    them: a spread asked for is a placeholder until `SpreadPass.run` computes it."""

    rows: np.ndarray
    requests: list[_Request] = field(default_factory=list)

    def spread(self, name: str, note: str, residual: Residual) -> Coefficient:
        """RMS of `residual` over the section's window samples (no interval): a placeholder
        coefficient now, replaced in the fits by `SpreadPass.fill`."""
        placeholder = Coefficient(name, math.nan, math.nan, math.nan, "N", 0, note=note)
        self.requests.append(_Request(placeholder, name, note, residual))
        return placeholder

    def clear(self) -> None:
        """Forget the spreads asked for (the fits are done again)."""
        self.requests.clear()


class SpreadPass:
    """The second pass: the sample spreads every section's fits asked for, in one read."""

    def __init__(self, run: RunData, windows: SteadyWindows) -> None:
        self.run = run
        self.first = windows.first
        self.sections: list[SectionSamples] = []
        self.local = np.full(len(run.steps), -1)
        self.section_of = np.full(len(run.steps), -1)

    def section(self, rows: np.ndarray) -> SectionSamples:
        """The samples of the section made of steps rows `rows`."""
        self.local[rows] = np.arange(rows.size)
        self.section_of[rows] = len(self.sections)
        self.sections.append(SectionSamples(rows))
        return self.sections[-1]

    def run_pass(self) -> dict[int, Coefficient]:
        """Read the window samples once and compute every spread asked for; returns the
        computed coefficient by id of its placeholder."""
        if not any(s.requests for s in self.sections):
            return {}
        for block in self.run.source.blocks(SPREAD_FIELDS):
            self._add(block)
        out = {}
        for sec in self.sections:
            for r in sec.requests:
                value = math.sqrt(r.sum_sq / r.n) if r.n else math.nan
                out[id(r.placeholder)] = (
                    Coefficient(r.name, value, math.nan, math.nan, "N", r.n, note=r.note)
                    if r.n else residual_spread(np.empty(0), r.name, r.note, interval=False))
        return out

    def _add(self, block: PointBlock) -> None:
        s = block.samples
        if not s.point.size:
            return
        rows = block.first_row + s.point
        pos = np.arange(s.point.size) - s.offsets[s.point] + block.start
        in_window = pos >= self.first[rows]
        point_section = self.section_of[block.rows]
        for k in np.unique(point_section):
            sec = self.sections[k] if k >= 0 else None
            if sec is None or not sec.requests:
                continue
            pick = in_window if (point_section == k).all() else (
                in_window & (point_section[s.point] == k))
            local = self.local[rows[pick]]
            channels = [_column(s, name, pick) for name in SPREAD_FIELDS]
            for r in sec.requests:
                res = r.residual(local, *channels)
                res = res[np.isfinite(res)]
                r.sum_sq += float(np.sum(res**2))
                r.n += int(res.size)


def _column(samples, name: str, pick: np.ndarray) -> np.ndarray:
    """A channel's picked samples (NaN where the channel was not recorded)."""
    x = getattr(samples, name)
    return np.full(int(pick.sum()), np.nan) if x is None else x[pick]


def fill_spreads(fits: dict[str, Coefficient], computed: dict[int, Coefficient]) -> None:
    """Replace the placeholders in `fits` by the spreads computed for them, in place."""
    for key, value in fits.items():
        if id(value) in computed:
            fits[key] = computed[id(value)]
