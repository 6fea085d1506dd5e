"""Steady-state window per point (block-mean settling criterion) and per-point statistics.

Each point's samples are cut into `n_blocks` equal blocks. The reference level is the median
of the block means over the second half; the window starts after the last block whose mean is
outside a tolerance of that reference (z times the scatter of the second half's block means
about a straight line, z times the white-noise standard error of a block, or a relative
tolerance, whichever is largest), but
never later than keeping `min_fraction` of the samples. The start is the latest one over the
channels that have data. Standard errors take autocorrelation into account: the larger of
the AR(1) effective-sample-size error, s / sqrt(n (1 - r1) / (1 + r1)), and the batch-means
error of the blocks inside the window.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from rigtool.analysis.dataset import Samples, Steps
from rigtool.analysis.stats import MAX_R1_SAMPLES, ar1_coefficient, effective_sample_size

CHANNEL_UNITS = {"thrust_n": "N", "speed_rpm": "r/min", "current_a": "A", "voltage_v": "V",
                 "power_w": "W", "torque_nm": "N m"}
MAX_ROUNDING = 0.05  # efficiency only where half a printed step moves power and thrust < 5 %
MIN_DISTINCT = 5  # a step is recognised in a channel with at least this many distinct values
MAX_STEP_DIVISOR = 10  # the step may be up to this many times finer than the smallest gap
RESOLUTION_SAMPLES = 200_000  # values looked at to find a channel's step
POOL_POINTS = 9  # a ramp bin's noise is pooled over this many consecutive bins


@dataclass(frozen=True)
class SettlingCriterion:
    """Parameters of the steady-window choice (recorded in calibration.json)."""

    n_blocks: int = 20
    min_fraction: float = 0.5
    z: float = 5.0
    rel_tol: float = 0.002
    min_samples: int = 80
    channels: tuple[str, ...] = ("thrust_n", "speed_rpm", "current_a")

    @property
    def max_start_block(self) -> int:
        return int(np.floor((1.0 - self.min_fraction) * self.n_blocks + 1e-9))


@dataclass
class ChannelStats:
    """Per-point statistics of one channel over the steady window (NaN where not measured)."""

    unit: str
    mean: np.ndarray
    std: np.ndarray
    se: np.ndarray
    min: np.ndarray
    max: np.ndarray

    @property
    def peak(self) -> np.ndarray:
        """The extreme on the side of the mean (max for positive means, min for negative).

        This is the "max" PWM rigs traditionally report beside the mean.
        """
        return np.where(self.mean >= 0, self.max, self.min)

    def take(self, index: np.ndarray) -> ChannelStats:
        return ChannelStats(self.unit, *(getattr(self, k)[index]
                                         for k in ("mean", "std", "se", "min", "max")))

    @property
    def measured(self) -> bool:
        return bool(np.isfinite(self.mean).any())


@dataclass
class PointTable:
    """One row per point (step): step metadata, steady window and channel statistics.

    t_mid_s is the mean sample time of the window (run clock); thrust_zero_n is the thrust
    zero (offset and drift) estimated for the point's depth, 0 when none could be estimated.
    """

    step_idx: np.ndarray
    command: np.ndarray
    depth_m: np.ndarray
    repeat: np.ndarray
    direction: np.ndarray
    t_start_s: np.ndarray
    status: np.ndarray
    settled: np.ndarray
    n_samples: np.ndarray
    n_window: np.ndarray
    window_start_s: np.ndarray
    t_mid_s: np.ndarray
    unsteady: np.ndarray
    thrust: ChannelStats
    speed: ChannelStats
    current: ChannelStats
    voltage: ChannelStats
    power: ChannelStats  # electrical power V * |I|, averaged sample by sample
    torque: ChannelStats  # torque about the thrust axis (six-axis sensors)
    dead: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    used_in_fits: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    thrust_zero_n: np.ndarray = field(default_factory=lambda: np.zeros(0))
    torque_zero_nm: np.ndarray = field(default_factory=lambda: np.zeros(0))
    speed_sign: np.ndarray = field(default_factory=lambda: np.zeros(0))  # set by the fits
    # d(n|n|)/dt over the window ((r/min)^2/s) where the command moves within it (a ramp's
    # bin), NaN where it is held: thrust and speed read through filters of their own then
    # differ by a lag times this (fits.fit_directional)
    speed_sq_rate: np.ndarray = field(default_factory=lambda: np.zeros(0))
    # Below these the data's own resolution (a table's printed step) decides the efficiency
    # more than MAX_ROUNDING: it is not reported there (empty: no floor).
    power_floor_w: np.ndarray = field(default_factory=lambda: np.zeros(0))
    thrust_floor_n: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def speed_signed_rpm(self) -> np.ndarray:
        """Mean speed with the direction the fits used (unsigned feedback gets a sign)."""
        n = self.speed.mean
        if self.speed_sign.size != n.size:
            return n
        return np.where(self.speed_sign != 0, np.abs(n) * self.speed_sign, n)

    @property
    def thrust_corrected_n(self) -> np.ndarray:
        """Mean thrust minus the estimated zero (offset + drift) at the point's time."""
        return self.thrust.mean - self.thrust_zero_n

    @property
    def torque_corrected_nm(self) -> np.ndarray:
        """Mean torque about the thrust axis minus its estimated zero (N m)."""
        zero = self.torque_zero_nm if self.torque_zero_nm.size else 0.0
        return self.torque.mean - zero

    def __len__(self) -> int:
        return len(self.step_idx)

    @property
    def kept_fraction(self) -> np.ndarray:
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.n_window / self.n_samples

    def take(self, index: np.ndarray) -> PointTable:
        """Rows `index` (int or bool array) as a new table."""
        stats = ("thrust", "speed", "current", "voltage", "power", "torque")
        plain = {k: getattr(self, k)[index] for k in self.__dataclass_fields__ if k not in stats}
        return PointTable(**plain, **{k: getattr(self, k).take(index) for k in stats})


@dataclass
class SteadyWindows:
    """Result of the window choice for every point of a run, plus the in-window sample mask."""

    criterion: SettlingCriterion
    first: np.ndarray
    window_start_s: np.ndarray
    t_mid_s: np.ndarray
    n_window: np.ndarray
    unsteady: np.ndarray
    channels: dict[str, ChannelStats]
    in_window: np.ndarray
    speed_sq_rate: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def point_table(self, steps: Steps, n_samples: np.ndarray,
                    resolutions: dict[str, float]) -> PointTable:
        """The run's point table; `resolutions`: the printed step of thrust, current and
        voltage (see `printed_step`; 0 or missing: none)."""
        n = len(steps)
        return PointTable(
            step_idx=steps.idx, command=steps.command, depth_m=steps.depth_m,
            repeat=steps.repeat, direction=steps.direction, t_start_s=steps.t_start_s,
            status=steps.status, settled=steps.settled, n_samples=n_samples,
            n_window=self.n_window, window_start_s=self.window_start_s, t_mid_s=self.t_mid_s,
            unsteady=self.unsteady, thrust=self.channels["thrust_n"],
            speed=self.channels["speed_rpm"], current=self.channels["current_a"],
            voltage=self.channels["voltage_v"], power=self.channels["power_w"],
            torque=self.channels["torque_nm"],
            dead=np.zeros(n, bool), used_in_fits=np.zeros(n, bool), thrust_zero_n=np.zeros(n),
            torque_zero_nm=np.zeros(n),
            speed_sign=np.zeros(n),
            speed_sq_rate=smooth_rates(self.speed_sq_rate, self.t_mid_s,
                                       self.channels["speed_rpm"].mean),
            **resolution_floors(self.channels, resolutions),
        )


def concat_windows(parts: list[SteadyWindows]) -> SteadyWindows:
    """The windows of consecutive blocks of points as one (without the per-sample mask)."""
    def cat(name: str) -> np.ndarray:
        return np.concatenate([getattr(w, name) for w in parts])

    channels = {}
    for name, unit in CHANNEL_UNITS.items():
        stats = [w.channels[name] for w in parts]
        channels[name] = ChannelStats(unit, *(np.concatenate([getattr(c, k) for c in stats])
                                              for k in ("mean", "std", "se", "min", "max")))
    return SteadyWindows(parts[0].criterion, cat("first"), cat("window_start_s"),
                         cat("t_mid_s"), cat("n_window"), cat("unsteady"), channels,
                         np.zeros(0, bool), cat("speed_sq_rate"))


RESOLUTION_CHANNELS = ("thrust_n", "current_a", "voltage_v")  # those `resolution_floors` uses


def resolution_stride(n_finite: int) -> int:
    """Every how many finite values `printed_step` is handed, of a channel with `n_finite`."""
    return n_finite // RESOLUTION_SAMPLES + 1 if n_finite > RESOLUTION_SAMPLES else 1


def printed_step(values: np.ndarray) -> float:
    """The step finite `values` are printed in (0.05 A, 0.01 kgf in N, ...): the smallest gap
    between distinct values, or a whole fraction of it, that every value is a whole multiple
    of; 0 when there is none (live readings) or too few distinct values to tell. The point
    pass hands it at most RESOLUTION_SAMPLES values of a channel, evenly strided."""
    v = np.unique(np.abs(values))
    gaps = np.diff(v)
    if v.size < MIN_DISTINCT or not (gaps > 0).any():
        return 0.0
    smallest = float(gaps[gaps > 0].min())
    for divisor in range(1, MAX_STEP_DIVISOR + 1):
        step = smallest / divisor
        ratio = v / step
        if ratio.max() < 1e9 and np.all(np.abs(ratio - np.round(ratio)) < 1e-6):
            return step
    return 0.0


def resolution_floors(channels: dict[str, ChannelStats], resolutions: dict[str, float]
                      ) -> dict[str, np.ndarray]:
    """Per point, the power and thrust below which half a printed step of current, voltage or
    thrust moves the efficiency by more than MAX_ROUNDING. A channel whose readings scatter
    by half a step or more within the point's window is dithered by its noise (rounding then
    biases its mean by under 1 % of a step; the standard error covers the rest) and sets no
    floor."""
    def step(name: str) -> np.ndarray:
        q = resolutions.get(name, 0.0)
        return np.where(np.nan_to_num(channels[name].std) < q / 2, q, 0.0)

    k = 1.0 / (2 * MAX_ROUNDING)
    volts, amps = np.abs(channels["voltage_v"].mean), np.abs(channels["current_a"].mean)
    power = k * (np.nan_to_num(volts) * step("current_a") + np.nan_to_num(amps) * step("voltage_v"))
    return {"power_floor_w": power, "thrust_floor_n": k * step("thrust_n")}


def steady_windows(samples: Samples, criterion: SettlingCriterion | None = None) -> SteadyWindows:
    """Choose the steady window of every point and compute per-point statistics over it."""
    crit = criterion or SettlingCriterion()
    n_points = len(samples.offsets) - 1
    nb = crit.n_blocks
    n = np.diff(samples.offsets)
    pid = samples.point
    pos = np.arange(pid.size) - samples.offsets[pid]
    blk = (pos * nb) // np.maximum(n[pid], 1)
    key = pid * nb + blk

    block_means: dict[str, np.ndarray] = {}
    outside = []
    for name in crit.channels:
        x = samples.channel(name)
        if not np.isfinite(x).any():
            continue
        block_means[name], out = _block_screen(x, key, n_points, crit)
        outside.append(out)
    start_blk, unsteady, short = window_starts(outside, n, crit)

    first = (start_blk * n + nb - 1) // nb
    in_window = blk >= start_blk[pid]
    t = samples.t_s
    has = n > 0
    window_start_s = np.full(n_points, np.nan)
    window_start_s[has] = (t[samples.offsets[:-1][has] + first[has]]
                           - t[samples.offsets[:-1][has]])
    n_window = n - first
    win_pid = pid[in_window]
    win_offsets = np.concatenate(([0], np.cumsum(n_window)))
    block_mask = window_blocks(start_blk, short, nb)
    with np.errstate(invalid="ignore", divide="ignore"):
        t_mid = np.bincount(win_pid, weights=t[in_window], minlength=n_points) / n_window
    stats = {}
    rate = _ramp_rates(samples, in_window, n_points)
    moving = np.isfinite(rate)
    for name, unit in CHANNEL_UNITS.items():
        if not samples.has(name):  # not recorded: no per-sample NaN arrays to build
            stats[name] = ChannelStats(unit, *(np.full(n_points, np.nan) for _ in range(5)))
            continue
        x = samples.channel(name)[in_window]
        batch_se = np.where(moving, np.nan, batch_means_se(block_means.get(name), block_mask))
        trend = _trend(x, t[in_window], win_pid, moving, n_points)
        stats[name] = _window_stats(x, win_pid, win_offsets, n_points, unit, batch_se, trend)
    return SteadyWindows(crit, first, window_start_s, t_mid, n_window, unsteady, stats, in_window,
                         rate)


def window_starts(outside: list[np.ndarray], n: np.ndarray, crit: SettlingCriterion
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per point, the first block of the window (the latest over the channels' masks of
    blocks `outside` the tolerance), whether it is unsteady, and whether it is too short to
    screen (`n` samples below the criterion's minimum: the whole point)."""
    nb = crit.n_blocks
    start_blk = np.zeros(n.size, dtype=np.int64)
    unsteady = np.zeros(n.size, dtype=bool)
    for out in outside:
        after_last = np.where(out.any(axis=1), nb - np.argmax(out[:, ::-1], axis=1), 0)
        unsteady |= after_last > crit.max_start_block
        start_blk = np.maximum(start_blk, np.minimum(after_last, crit.max_start_block))
    short = n < crit.min_samples
    start_blk[short] = 0
    unsteady[short] = False
    return start_blk, unsteady, short


def window_blocks(start_blk: np.ndarray, short: np.ndarray, nb: int) -> np.ndarray:
    """Mask (points x blocks) of the blocks inside each window, for batch means."""
    return (np.arange(nb)[None, :] >= start_blk[:, None]) & ~short[:, None]


def smooth_rates(rate: np.ndarray, t_s: np.ndarray, speed: np.ndarray) -> np.ndarray:
    """The d(n|n|)/dt of moving points (`rate`: each one's slope over its own few samples, NaN
    where held) from the point means instead: the gradient of n|n| against time along each run
    of consecutive moving points that go one way (a one-way stretch of a ramp), which the
    speed noise moves far less than a slope over one bin. A run of one point keeps `rate`."""
    out = np.array(rate, dtype=float) if rate.size == t_s.size else np.full(t_s.size, np.nan)
    x = speed * np.abs(speed)
    ok = np.isfinite(out) & np.isfinite(x) & np.isfinite(t_s)
    same = ok[1:] & ok[:-1] & (np.sign(out[1:]) == np.sign(out[:-1])) & (np.diff(t_s) > 0)
    starts = np.flatnonzero(np.concatenate(([True], ~same)))
    stops = np.append(starts[1:], t_s.size)
    for a, b in zip(starts.tolist(), stops.tolist(), strict=True):
        if b - a >= 2 and ok[a]:
            out[a:b] = np.gradient(x[a:b], t_s[a:b])
    return out


def _trend(x: np.ndarray, t: np.ndarray, pid: np.ndarray, moving: np.ndarray,
           n_points: int) -> np.ndarray | None:
    """Per sample, its point's least-squares line in time less the point's mean, for the
    `moving` points (a ramp's bins: the command moves within the window), 0 elsewhere: the
    trend the command makes is not noise. None: 0 everywhere."""
    if not moving.any():
        return None
    ok = np.isfinite(x) & moving[pid]
    if not ok.any():
        return None
    w = ok.astype(float)
    with np.errstate(invalid="ignore", divide="ignore"):
        count = np.bincount(pid, w, n_points)
        dt = np.where(ok, t - (np.bincount(pid, w * t, n_points) / count)[pid], 0.0)
        dx = np.where(ok, x - (np.bincount(pid, np.where(ok, x, 0.0), n_points) / count)[pid],
                      0.0)
        slope = np.bincount(pid, dt * dx, n_points) / np.bincount(pid, dt * dt, n_points)
    return np.where(ok, np.nan_to_num(slope)[pid] * dt, 0.0)


def _pooled(c0: np.ndarray, c1: np.ndarray, dof: np.ndarray,
            sloped: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sums of squares, lag-1 products and degrees of freedom of each `sloped` point (a
    ramp bin, a few samples about its line) pooled with its neighbours' over POOL_POINTS
    consecutive sloped points, so a bin of three rows is not given a noise of one degree of
    freedom; the noise changes slowly along a ramp. Other points keep their own."""
    out = [np.array(v, dtype=float) for v in (c0, c1, dof)]
    edges = np.flatnonzero(np.diff(np.concatenate(([0], sloped.astype(np.int8), [0]))))
    half = POOL_POINTS // 2
    for a, b in zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True):
        lo = np.clip(np.arange(a, b) - half, a, max(b - POOL_POINTS, a))
        hi = np.minimum(lo + POOL_POINTS, b)
        for v, src in zip(out, (c0, c1, dof), strict=True):
            total = np.concatenate(([0.0], np.cumsum(np.nan_to_num(src[a:b]))))
            v[a:b] = total[hi - a] - total[lo - a]
    return out[0], out[1], out[2]


def _ramp_rates(samples: Samples, in_window: np.ndarray, n_points: int) -> np.ndarray:
    """Per point, the least-squares slope of n|n| against time over its window where the
    command moves within the window (NaN where it is held, unknown, or fewer than 2 samples)."""
    out = np.full(n_points, np.nan)
    cmd, speed = samples.command, samples.speed_rpm
    if cmd is None or speed is None or not in_window.any():
        return out
    if not _command_moves(cmd[in_window], samples.point[in_window], n_points):
        return out
    pid, t = samples.point[in_window], samples.t_s[in_window]
    c, x = cmd[in_window], speed[in_window] * np.abs(speed[in_window])
    ok = np.isfinite(c) & np.isfinite(x) & np.isfinite(t)
    pid, t, c, x = pid[ok], t[ok], c[ok], x[ok]
    if not pid.size:
        return out
    count = np.bincount(pid, minlength=n_points)
    with np.errstate(invalid="ignore", divide="ignore"):
        lo = np.full(n_points, np.inf)
        hi = np.full(n_points, -np.inf)
        np.minimum.at(lo, pid, c)
        np.maximum.at(hi, pid, c)
        dt = t - (np.bincount(pid, t, n_points) / count)[pid]
        dx = x - (np.bincount(pid, x, n_points) / count)[pid]
        slope = np.bincount(pid, dt * dx, n_points) / np.bincount(pid, dt * dt, n_points)
    moving = (count >= 2) & (hi > lo) & np.isfinite(slope)
    out[moving] = slope[moving]
    return out


def _command_moves(c: np.ndarray, pid: np.ndarray, n_points: int) -> bool:
    """Whether the command `c` (window samples of points `pid`, ascending) takes two values
    within any one point: a quick test before the ramp slopes, which need one."""
    count = np.bincount(pid, minlength=n_points)
    has = np.flatnonzero(count)
    if not has.size:
        return False
    starts = (np.cumsum(count) - count)[has]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return bool((np.fmax.reduceat(c, starts) > np.fmin.reduceat(c, starts)).any())


def point_channel_stats(x: np.ndarray, offsets: np.ndarray, unit: str,
                        n_blocks: int = SettlingCriterion.n_blocks) -> ChannelStats:
    """Per-point statistics of any channel (e.g. an F/T channel) over all of each point's
    samples (point p owns x[offsets[p]:offsets[p + 1]]): mean, and a standard error that takes
    autocorrelation into account as the steady windows' do (AR(1) or batch means, the larger)."""
    n_points = len(offsets) - 1
    n = np.diff(offsets)
    pid = np.repeat(np.arange(n_points), n)
    pos = np.arange(pid.size) - offsets[pid]
    key = pid * n_blocks + (pos * n_blocks) // np.maximum(n[pid], 1)
    ok = np.isfinite(x)
    cnt = np.bincount(key[ok], minlength=n_points * n_blocks).reshape(n_points, n_blocks)
    total = np.bincount(key[ok], weights=x[ok], minlength=n_points * n_blocks)
    with np.errstate(invalid="ignore", divide="ignore"):
        means = total.reshape(n_points, n_blocks) / cnt
    return _window_stats(x, pid, offsets, n_points, unit,
                         batch_means_se(means, np.ones_like(means, dtype=bool)), np.zeros_like(x))


def _block_screen(x: np.ndarray, key: np.ndarray, n_points: int,
                  crit: SettlingCriterion) -> tuple[np.ndarray, np.ndarray]:
    """Block means (points x blocks) and the mask of blocks outside the settling tolerance."""
    nb = crit.n_blocks
    size = n_points * nb
    ok = np.isfinite(x)
    every = bool(ok.all())
    xv = x if every else np.where(ok, x, 0.0)
    cnt = np.bincount(key, weights=None if every else ok, minlength=size).astype(float)
    cnt = cnt.reshape(n_points, nb)
    with np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        means = np.bincount(key, weights=xv, minlength=size).reshape(n_points, nb) / cnt
        dev = xv - means.ravel()[key]
        if not every:
            dev[~ok] = 0.0
        ss = np.bincount(key, weights=dev * dev, minlength=size).reshape(n_points, nb)
    return means, screen_blocks(cnt, means, ss, crit)


def screen_blocks(cnt: np.ndarray, means: np.ndarray, ss: np.ndarray,
                  crit: SettlingCriterion) -> np.ndarray:
    """The mask of blocks outside the settling tolerance, from each block's count, mean and
    sum of squares about its mean (points x blocks)."""
    nb = crit.n_blocks
    with np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        tail = slice(nb // 2, nb)
        ref = _nanmedian(means[:, tail])
        scatter = _detrended_scatter(means[:, tail])
        within = ss[:, tail].sum(axis=1) / np.maximum(cnt[:, tail] - 1, 0).sum(axis=1)
        block_se = np.sqrt(within / np.nanmean(cnt[:, tail], axis=1))
    tol = np.fmax(np.fmax(crit.z * scatter, crit.z * block_se), crit.rel_tol * np.abs(ref))
    tol = np.fmax(tol, 1e-12)
    with np.errstate(invalid="ignore"):
        return np.abs(means - ref[:, None]) > tol[:, None]


def _detrended_scatter(means: np.ndarray) -> np.ndarray:
    """Residual std of block means about a straight line (a trend is not counted as noise)."""
    k = np.isfinite(means).sum(axis=1)
    x = np.arange(means.shape[1], dtype=float)
    x = np.where(np.isfinite(means), x - np.nanmean(np.where(np.isfinite(means), x, np.nan),
                                                    axis=1, keepdims=True), 0.0)
    y = means - np.nanmean(means, axis=1, keepdims=True)
    y = np.where(np.isfinite(y), y, 0.0)
    slope = (x * y).sum(axis=1) / (x * x).sum(axis=1)
    resid = y - slope[:, None] * x
    return np.sqrt((resid * resid).sum(axis=1) / (k - 2))


def batch_means_se(means: np.ndarray | None, mask: np.ndarray) -> np.ndarray:
    """Batch-means standard error of the blocks inside each window (NaN if unavailable)."""
    if means is None:
        return np.full(mask.shape[0], np.nan)
    m = np.where(mask & np.isfinite(means), means, np.nan)
    k = np.isfinite(m).sum(axis=1)
    with warnings.catch_warnings(), np.errstate(invalid="ignore", divide="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        sd = np.nanstd(m, axis=1, ddof=1)
    return np.where(k >= 3, sd / np.sqrt(k), np.nan)


def _window_stats(x: np.ndarray, pid: np.ndarray, offsets: np.ndarray, n_points: int,
                  unit: str, batch_se: np.ndarray, trend: np.ndarray | None) -> ChannelStats:
    """Mean, std, standard error, min and max per point; std and error about `trend` (a ramp
    bin's line in time, see `_trend`; one degree of freedom fewer where it is not 0; None:
    0 everywhere). Where every value is finite the masks are left out (the same sums)."""
    ok = np.isfinite(x)
    every = bool(ok.all())
    xv = x if every else np.where(ok, x, 0.0)
    cnt = (np.diff(offsets).astype(float) if every
           else np.bincount(pid, weights=ok, minlength=n_points))
    sloped = (np.zeros(n_points, bool) if trend is None
              else np.bincount(pid, weights=trend != 0, minlength=n_points) > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.bincount(pid, weights=xv, minlength=n_points) / cnt
        dev = xv - mean[pid]
        if trend is not None:
            dev -= trend
        if not every:
            dev[~ok] = 0.0
        c0 = np.bincount(pid, weights=dev * dev, minlength=n_points)
        # Lag-1 products within each point: one across a point boundary counts 0 (sums of
        # the same terms as over the pairs within points).
        lag = dev[1:] * dev[:-1]
        lag[pid[1:] != pid[:-1]] = 0.0
        c1 = np.bincount(pid[:-1], weights=lag, minlength=n_points)
    lo = np.full(n_points, np.nan)
    hi = np.full(n_points, np.nan)
    nonempty = np.flatnonzero(np.diff(offsets) > 0)
    if nonempty.size and ok.any():
        starts = offsets[nonempty]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            lo[nonempty] = np.fmin.reduceat(x, starts)
            hi[nonempty] = np.fmax.reduceat(x, starts)
    return channel_stats(unit, WindowSums(cnt, mean, c0, c1, sloped, lo, hi), batch_se)


@dataclass
class WindowSums:
    """What a channel's window statistics are made of, per point: finite samples, mean,
    sum of squares and of lag-1 products about the mean (less the trend), whether a trend was
    taken out, and the extremes (NaN: none)."""

    cnt: np.ndarray
    mean: np.ndarray
    c0: np.ndarray
    c1: np.ndarray
    sloped: np.ndarray
    lo: np.ndarray
    hi: np.ndarray


def channel_stats(unit: str, sums: WindowSums, batch_se: np.ndarray) -> ChannelStats:
    """A channel's ChannelStats from its window sums (see `_window_stats`)."""
    cnt, mean, lo, hi = sums.cnt, sums.mean, sums.lo, sums.hi
    with np.errstate(invalid="ignore", divide="ignore"):
        dof = cnt - 1 - sums.sloped
        c0, c1, dof = _pooled(sums.c0, sums.c1, np.maximum(dof, 0), sums.sloped)
        var = np.where(dof > 0, c0 / dof, np.nan)
        std = np.sqrt(var)
        r1 = ar1_coefficient(c1 / c0, MAX_R1_SAMPLES)
        n_eff = effective_sample_size(cnt, r1, 1.0)
        se_ar1 = std / np.sqrt(n_eff)
    se = np.fmax(se_ar1, batch_se)
    mean = np.where(cnt > 0, mean, np.nan)
    # A channel that never varies in the window (one reading repeated, as a table row is
    # stored) shows no error: its standard error is unknown, not zero (nor rounding noise).
    flat = lo == hi
    se = np.where((cnt > 1) & ~flat, se, np.nan)
    std = np.where(cnt > 1, np.where(flat, 0.0, std), np.nan)
    return ChannelStats(unit, mean, std, se, lo, hi)


def _nanmedian(a: np.ndarray) -> np.ndarray:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmedian(a, axis=1)
