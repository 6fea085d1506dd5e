"""The steady window and window statistics of one point longer than a block, streamed.

`steady.steady_windows` holds a block of whole points at once. A point longer than a block
(an endurance dwell: an hour at 7 kHz is 25 M samples) is read here in pieces, once per
pass: the block sums, the blocks' spreads (the window start follows), the window's sums
and extremes, a ramp's slopes (only where the command moves), and the spreads about the
mean. Every per-sample sum is carried from piece to piece in sample order, as one
np.bincount over the whole point adds it, so the statistics equal steady_windows' on the
whole point. Memory is one piece, whatever the point's length.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from rigtool.analysis.dataset import SAMPLE_FIELDS, Samples, SampleSource
from rigtool.analysis.steady import (
    CHANNEL_UNITS,
    ChannelStats,
    SettlingCriterion,
    SteadyWindows,
    WindowSums,
    batch_means_se,
    channel_stats,
    screen_blocks,
    window_blocks,
    window_starts,
)

FIELDS = (*SAMPLE_FIELDS, "torque_nm", "command")


class _Running:
    """Sums by key (0 .. size - 1) over a point's pieces, each piece continuing the running
    totals in sample order: the same additions, in the same order, as one np.bincount."""

    def __init__(self, size: int = 1) -> None:
        self.total = np.zeros(size)
        self._keys = np.arange(size)

    def add(self, weights: np.ndarray, key: np.ndarray | None = None) -> None:
        size = self.total.size
        k = np.zeros(weights.size, np.int64) if key is None else key
        self.total = np.bincount(np.concatenate((self._keys, k)),
                                 np.concatenate((self.total, weights)), minlength=size)


def _pieces(source: SampleSource, row: int, start: int = 0
            ) -> Iterator[tuple[np.ndarray, Samples]]:
    """(positions in the point, samples) of each piece of steps row `row`, from `start` on."""
    for block in source.pieces(row, FIELDS):
        s = block.samples
        pos = block.start + np.arange(s.t_s.size)
        if pos.size and pos[-1] >= start:
            yield pos, s


def _channel(s: Samples, name: str, sign: float) -> np.ndarray:
    """A channel of a piece; power with its point's current sign (`Samples.channel` takes
    the sign from the samples it holds, here a piece)."""
    if name == "power_w":
        return s.channel("voltage_v") * s.current_a * sign
    return s.channel(name)


def _current_sign(source: SampleSource, row: int) -> float:
    """The sign power takes for the point: that of its current's sum over all samples."""
    total = _Running()
    for _, s in _pieces(source, row):
        total.add(np.nan_to_num(s.current_a))
    return -1.0 if total.total[0] < 0 else 1.0


def _block_means(source: SampleSource, row: int, n: int, crit: SettlingCriterion
                 ) -> tuple[dict[str, tuple[np.ndarray, ...]], float]:
    """Per screened channel with data: the count, mean and sum of squares about the mean of
    each of the point's `n_blocks` blocks (two passes: sums, then squares); and the sign
    power takes (see `_current_sign`, taken in the first pass)."""
    nb = crit.n_blocks
    sign = _current_sign(source, row) if "power_w" in crit.channels else 1.0
    cnt = {c: np.zeros(nb) for c in crit.channels}
    sums = {c: _Running(nb) for c in crit.channels}
    current = _Running()
    for pos, s in _pieces(source, row):
        key = (pos * nb) // max(n, 1)
        current.add(np.nan_to_num(s.current_a))
        for name in crit.channels:
            x = _channel(s, name, sign)
            ok = np.isfinite(x)
            cnt[name] += np.bincount(key, weights=ok, minlength=nb)
            sums[name].add(np.where(ok, x, 0.0), key)
    with np.errstate(invalid="ignore", divide="ignore"):
        means = {c: sums[c].total / cnt[c] for c in crit.channels if cnt[c].any()}
    squares = {c: _Running(nb) for c in means}
    for pos, s in _pieces(source, row):
        key = (pos * nb) // max(n, 1)
        for name in means:
            x = _channel(s, name, sign)
            ok = np.isfinite(x)
            dev = np.where(ok, np.where(ok, x, 0.0) - means[name][key], 0.0)
            squares[name].add(dev * dev, key)
    blocks = {c: (cnt[c][None], means[c][None], squares[c].total[None]) for c in means}
    return blocks, (-1.0 if current.total[0] < 0 else 1.0)


class _WindowPass:
    """The window's sums over samples first .. n - 1 of a point: each channel's count, sum,
    extremes and time sum (for a ramp's trend), the time sum, and the ramp's command range
    and sums of time and n|n|."""

    def __init__(self, channels: list[str], sign: float) -> None:
        self.channels, self.sign = channels, sign
        self.cnt = dict.fromkeys(channels, 0.0)
        self.sum = {c: _Running() for c in channels}
        self.t_ok = {c: _Running() for c in channels}
        self.lo = dict.fromkeys(channels, np.nan)
        self.hi = dict.fromkeys(channels, np.nan)
        self.t_sum, self.t_first = _Running(), np.nan
        self.ramp_n, self.ramp_t, self.ramp_x = 0, _Running(), _Running()
        self.c_lo, self.c_hi = np.inf, -np.inf

    def add(self, s: Samples, win: np.ndarray) -> None:
        t = s.t_s[win]
        self.t_sum.add(t)
        for name in self.channels:
            x = _channel(s, name, self.sign)[win]
            ok = np.isfinite(x)
            self.cnt[name] += float(ok.sum())
            self.sum[name].add(np.where(ok, x, 0.0))
            self.t_ok[name].add(ok.astype(float) * t)
            if x.size:
                self.lo[name] = np.fmin(self.lo[name], np.fmin.reduce(x))
                self.hi[name] = np.fmax(self.hi[name], np.fmax.reduce(x))
        ramp = _ramp_samples(s, win)
        if ramp is not None:
            c, tr, xr = ramp
            self.ramp_n += tr.size
            if tr.size:
                self.c_lo, self.c_hi = min(self.c_lo, c.min()), max(self.c_hi, c.max())
            self.ramp_t.add(tr)
            self.ramp_x.add(xr)

    def mean(self, name: str) -> float:
        with np.errstate(invalid="ignore", divide="ignore"):
            return float(np.float64(self.sum[name].total[0]) / self.cnt[name])


def _ramp_samples(s: Samples, win: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """A piece's window samples a ramp's slope is taken over: command, time and n|n| where
    all three are finite (None: no command or speed read)."""
    if s.command is None or s.speed_rpm is None:
        return None
    c, t, speed = s.command[win], s.t_s[win], s.speed_rpm[win]
    x = speed * np.abs(speed)
    ok = np.isfinite(c) & np.isfinite(x) & np.isfinite(t)
    return c[ok], t[ok], x[ok]


def _slopes(source: SampleSource, row: int, first: int, w: _WindowPass
            ) -> tuple[float, dict[str, float]]:
    """A moving point's slope of n|n| in time (NaN: none) and each channel's slope in time
    (the trend its window statistics are taken about)."""
    ramp_dtdx, ramp_dtdt = _Running(), _Running()
    dtdx = {c: _Running() for c in w.channels}
    dtdt = {c: _Running() for c in w.channels}
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_t, mean_x = w.ramp_t.total[0] / w.ramp_n, w.ramp_x.total[0] / w.ramp_n
        t_means = {c: w.t_ok[c].total[0] / w.cnt[c] for c in w.channels}
        for pos, s in _pieces(source, row, first):
            win = pos >= first
            _, tr, xr = _ramp_samples(s, win)  # type: ignore[misc]
            dt, dx = tr - mean_t, xr - mean_x
            ramp_dtdx.add(dt * dx)
            ramp_dtdt.add(dt * dt)
            t = s.t_s[win]
            for name in w.channels:
                x = _channel(s, name, w.sign)[win]
                ok = np.isfinite(x)
                dt = np.where(ok, t - t_means[name], 0.0)
                dx = np.where(ok, x - w.mean(name), 0.0)
                dtdx[name].add(dt * dx)
                dtdt[name].add(dt * dt)
        rate = float(ramp_dtdx.total[0] / ramp_dtdt.total[0])
        slopes = {c: float(np.nan_to_num(dtdx[c].total[0] / dtdt[c].total[0]))
                  for c in w.channels}
    return rate, slopes


def _spreads(source: SampleSource, row: int, first: int, w: _WindowPass,
             slopes: dict[str, float] | None) -> dict[str, WindowSums]:
    """Each channel's window sums: squares and lag-1 products about its mean (less its trend,
    where `slopes` are given), the lag carried across pieces."""
    c0 = {c: _Running() for c in w.channels}
    c1 = {c: _Running() for c in w.channels}
    last: dict[str, np.ndarray] = {c: np.empty(0) for c in w.channels}
    sloped = dict.fromkeys(w.channels, False)
    for pos, s in _pieces(source, row, first):
        win = pos >= first
        t = s.t_s[win]
        for name in w.channels:
            x = _channel(s, name, w.sign)[win]
            ok = np.isfinite(x)
            mean = w.mean(name)
            trend = np.zeros(x.size)
            if slopes is not None and ok.any():
                with np.errstate(invalid="ignore", divide="ignore"):
                    t_mean = w.t_ok[name].total[0] / w.cnt[name]
                dt = np.where(ok, t - t_mean, 0.0)
                trend = np.where(ok, slopes[name] * dt, 0.0)
            sloped[name] |= bool((trend != 0).any())
            dev = np.where(ok, np.where(ok, x, 0.0) - mean - trend, 0.0)
            c0[name].add(dev * dev)
            both = np.concatenate((last[name], dev))
            c1[name].add(both[1:] * both[:-1])
            last[name] = dev[-1:]
    return {c: WindowSums(np.array([w.cnt[c]]), np.array([w.mean(c)]), c0[c].total,
                          c1[c].total, np.array([sloped[c]]), np.array([w.lo[c]]),
                          np.array([w.hi[c]])) for c in w.channels}


def long_point_windows(source: SampleSource, row: int,
                       crit: SettlingCriterion) -> SteadyWindows:
    """The steady window and statistics of steps row `row`, read in pieces (see the module)."""
    n = int(source.point_counts()[row])
    nb = crit.n_blocks
    blocks, sign = _block_means(source, row, n, crit)
    outside = [screen_blocks(cnt, means, ss, crit) for cnt, means, ss in blocks.values()]
    start_blk, unsteady, short = window_starts(outside, np.array([n]), crit)
    first = (start_blk * n + nb - 1) // nb
    start = int(first[0])
    w = _WindowPass([c for c in CHANNEL_UNITS if c != "torque_nm" or source.has_torque], sign)
    t0 = t_start = np.nan
    for pos, s in _pieces(source, row):
        win = pos >= start
        if pos[0] == 0:
            t0 = s.t_s[0]
        if pos[0] <= start <= pos[-1]:
            t_start = s.t_s[start - pos[0]]
        w.add(s, win)
    rate, slopes = np.nan, None
    if w.ramp_n >= 2 and w.c_hi > w.c_lo:
        rate, slopes = _slopes(source, row, start, w)
    moving = np.isfinite(rate)
    sums = _spreads(source, row, start, w, slopes if moving else None)
    mask = window_blocks(start_blk, short, nb)
    stats = {}
    for name, unit in CHANNEL_UNITS.items():
        if name not in sums:
            stats[name] = ChannelStats(unit, *(np.full(1, np.nan) for _ in range(5)))
            continue
        means = blocks[name][1] if name in blocks else None
        batch_se = np.where(moving, np.nan, batch_means_se(means, mask))
        stats[name] = channel_stats(unit, sums[name], batch_se)
    n_window = np.array([n]) - first
    with np.errstate(invalid="ignore", divide="ignore"):
        t_mid = w.t_sum.total / n_window
    return SteadyWindows(crit, first, np.array([t_start - t0]), t_mid, n_window, unsteady,
                         stats, np.zeros(0, bool), np.array([rate if moving else np.nan]))
