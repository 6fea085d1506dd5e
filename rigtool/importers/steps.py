"""Group parsed rows into points: a time series by runs of equal command, a table row by row.

Points are built column-wise with numpy (no Python work per point), so a log of a million
rows that are each their own point imports in seconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rigtool.errors import UsageError
from rigtool.importers.generic import Parsed

TORQUE_CHANNEL = "tx"
TEMPERATURE_CHANNEL = "temperature_c"

# parsed field -> sample channel; torque is stored as `tx`, the torque about a thrust axis on
# `fx` (the run's rig says so); `temperature_c` has no sample column in the store: the import
# keeps it per point in `temperature` events (rigtool.importers.temperature_events)
CHANNELS = {"thrust": "thrust_n", "speed": "speed_rpm", "current": "current_a",
            "voltage": "voltage_v", "torque": TORQUE_CHANNEL, "temperature": TEMPERATURE_CHANNEL}
MAX_SYNTH_SAMPLES = 10_000
MAX_IMPORT_SAMPLES = 10_000_000  # samples one import may synthesise from a per-point table
TIMESERIES_MIN_RUN = 3  # median rows per command above which `auto` reads a time series
RAMP_MAX_DT_S = 1.0  # a log sampled faster than this whose command moves on most rows: a ramp
RAMP_MIN_ROWS = 20
RAMP_ROWS_PER_POINT = 5  # a ramp's command bins hold at least this many rows ...
RAMP_MAX_POINTS = 200  # ... and there are at most this many of them
RAMP_HOLD_SETTLE_S = 3.0  # a ramp's held command drops this much (at most half) after its step
MAX_LISTED_DROPS = 10  # dropped points named one by one; the rest are counted
NO_DEPTH = -1e300  # stands for "no depth" in grouping keys


@dataclass
class ImportedPoints:
    """Every point of an imported run, column-wise; point i owns samples[bounds[i]:bounds[i + 1]].

    `depth_m` (`voltage_v`, the supply voltage set) is NaN where a point has none; `direction`
    holds "up" or "down".
    """

    command: np.ndarray
    depth_m: np.ndarray
    voltage_v: np.ndarray
    repeat: np.ndarray
    direction: np.ndarray
    t_start_s: np.ndarray
    t_acquire_s: np.ndarray
    t_end_s: np.ndarray
    settle_s: np.ndarray
    rate_hz: np.ndarray
    bounds: np.ndarray
    samples: dict[str, np.ndarray]

    def __len__(self) -> int:
        return int(self.command.size)

    def columns(self) -> dict[str, np.ndarray]:
        """The per-point fields by steps-table column name."""
        names = ("command", "depth_m", "repeat", "direction", "t_start_s", "t_acquire_s",
                 "t_end_s", "settle_s", "rate_hz")
        return {**{n: getattr(self, n) for n in names}, "voltage_set_v": self.voltage_v}


def _edges(keys: np.ndarray) -> np.ndarray:
    """Start of every run of equal keys, then the number of rows."""
    if keys.shape[0] == 0:
        return np.zeros(1, dtype=int)
    change = np.flatnonzero(np.any(keys[1:] != keys[:-1], axis=1)) + 1
    return np.concatenate(([0], change, [keys.shape[0]]))


def _keys(p: Parsed, depth_m: float | None) -> np.ndarray:
    cmd = p.values["command"]
    depth = p.values.get("depth", np.full(cmd.size, np.nan if depth_m is None else depth_m))
    supply = p.values.get("supply", np.full(cmd.size, np.nan))
    return np.column_stack([cmd, np.nan_to_num(depth, nan=NO_DEPTH),
                            np.nan_to_num(supply, nan=NO_DEPTH)])


def choose_format(p: Parsed, requested: str, depth_m: float | None) -> str:
    """`points` for per-point tables, `timeseries` for logs holding each command for many rows."""
    if requested != "auto":
        return requested
    if "thrust_std" in p.values or "n_samples" in p.values or "time" not in p.values:
        return "points"
    lengths = np.diff(_edges(_keys(p, depth_m)))
    if lengths.size and np.median(lengths) >= TIMESERIES_MIN_RUN:
        return "timeseries"
    dt = np.diff(p.values["time"])
    if p.lines.size >= RAMP_MIN_ROWS and dt.size and 0 < np.median(dt) < RAMP_MAX_DT_S:
        return "ramp"
    return "points"


def ramp_keys(p: Parsed, depth_m: float | None) -> np.ndarray:
    """Grouping keys of a command ramp: the command's bin, of a width that puts at least
    RAMP_ROWS_PER_POINT rows in a bin and makes at most RAMP_MAX_POINTS bins over the range
    (consecutive rows in one bin are one point; a ramp back down makes points of its own).
    The top of the range belongs to the last bin: a bin of its own would hold the one row
    there, a point whose error nothing in it shows. A command held for TIMESERIES_MIN_RUN
    rows or more (neutral at the ends) keeps its own value: it is a point of its own, not
    part of a bin."""
    keys = _keys(p, depth_m)
    cmd = keys[:, 0].copy()
    finite = cmd[np.isfinite(cmd)]
    span = float(np.ptp(finite)) if finite.size else 0.0
    bins = max(min(RAMP_MAX_POINTS, finite.size // RAMP_ROWS_PER_POINT), 1)
    if span > 0:
        width = span / bins
        index = np.minimum(np.floor((cmd - finite.min()) / width), bins - 1)
        keys[:, 0] = finite.min() + (index + 0.5) * width
    edges = _edges(_keys(p, depth_m))
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        if b - a >= TIMESERIES_MIN_RUN:
            keys[a:b, 0] = cmd[a:b]
    return keys


def _depths(p: Parsed, rows: np.ndarray, depth_m: float | None) -> np.ndarray:
    """Depth of each given row: its depth cell if readable, else `depth_m` (NaN for none)."""
    fallback = np.nan if depth_m is None else depth_m
    d = p.values.get("depth")
    if d is None:
        return np.full(rows.size, fallback)
    return np.where(np.isfinite(d[rows]), d[rows], fallback)


def _supplies(p: Parsed, rows: np.ndarray) -> np.ndarray:
    """Supply voltage set for each given row (NaN without a supply column or cell)."""
    s = p.values.get("supply")
    return np.full(rows.size, np.nan) if s is None else s[rows]


def _labels(command: np.ndarray, depth: np.ndarray,
            voltage: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Repeat index per (command, depth, voltage) in order of appearance, and the sweep
    direction."""
    if command.size == 0:
        return np.zeros(0, dtype=int), np.zeros(0, dtype=str)
    keys = np.column_stack([command, np.nan_to_num(depth, nan=NO_DEPTH),
                            np.nan_to_num(voltage, nan=NO_DEPTH)])
    group = np.unique(keys, axis=0, return_inverse=True)[1].ravel()
    order = np.argsort(group, kind="stable")
    ordered = group[order]
    pos = np.arange(order.size)
    first = np.concatenate(([True], ordered[1:] != ordered[:-1]))
    rank = pos - np.maximum.accumulate(np.where(first, pos, 0)) + 1
    repeat = np.empty_like(rank)
    repeat[order] = rank
    down = np.concatenate(([False], command[1:] < command[:-1]))
    return repeat, np.where(down, "down", "up")


def _group_medians(values: np.ndarray, group: np.ndarray, n_groups: int) -> np.ndarray:
    """Median of `values` per group (NaN for an empty group or one holding a NaN)."""
    out = np.full(n_groups, np.nan)
    if values.size == 0:
        return out
    order = np.lexsort((values, group))
    v, g = values[order], group[order]
    counts = np.bincount(g, minlength=n_groups)
    starts = np.concatenate(([0], np.cumsum(counts)[:-1]))
    has = counts > 0
    lo = v[(starts + (counts - 1) // 2)[has]]
    hi = v[(starts + counts // 2)[has]]
    out[has] = (lo + hi) / 2
    out[np.bincount(g, weights=np.isnan(v), minlength=n_groups) > 0] = np.nan
    return out


def _dropped_warnings(p: Parsed, starts: np.ndarray, lengths: np.ndarray,
                      settle_s: float) -> list[str]:
    """One warning per dropped point, up to MAX_LISTED_DROPS, then a count of the rest."""
    out = [f"command {p.values['command'][a]:g} at line {p.lines[a]}: all {n} row(s) inside the "
           f"{settle_s:g} s settling time; point dropped"
           for a, n in zip(starts[:MAX_LISTED_DROPS].tolist(), lengths[:MAX_LISTED_DROPS].tolist(),
                           strict=True)]
    if starts.size > MAX_LISTED_DROPS:
        out.append(f"{starts.size - MAX_LISTED_DROPS} more point(s) dropped: all their rows "
                   f"inside the {settle_s:g} s settling time")
    return out


def timeseries_steps(p: Parsed, settle_s: float, depth_m: float | None,
                     keys: np.ndarray | None = None) -> tuple[ImportedPoints, list[str]]:
    """One point per run of equal command (equal `keys`, given: a ramp's command bins, each
    point's command then the mean of its rows'); the first `settle_s` of each run is dropped.
    With `keys`, a command held for TIMESERIES_MIN_RUN rows or more (a ramp's neutral ends)
    drops its first RAMP_HOLD_SETTLE_S instead, at most half of it: after a step the thrust
    still follows the propeller's spin-up or spin-down, which would read as a zero drift."""
    t = p.values["time"]
    t = t - t[0] if t.size else t
    warnings = []
    if t.size > 1 and np.any(np.diff(t) < 0):
        warnings.append("time column goes backwards: rows are kept in file order")
    edges = _edges(_keys(p, depth_m) if keys is None else keys)
    starts, stops = edges[:-1], edges[1:]
    run_of_row = np.repeat(np.arange(starts.size), stops - starts)
    settle = np.full(starts.size, float(settle_s))
    if keys is not None:
        cmd = p.values["command"]
        held = ((stops - starts >= TIMESERIES_MIN_RUN)
                & (cmd[starts] == cmd[stops - 1]) & (keys[starts, 0] == cmd[starts]))
        span = t[stops - 1] - t[starts]
        settle = np.where(held, np.minimum(RAMP_HOLD_SETTLE_S, 0.5 * span), settle)
    keep = t >= (t[starts] + settle)[run_of_row]
    kept_per_run = np.bincount(run_of_row[keep], minlength=starts.size)
    empty = kept_per_run == 0
    warnings += _dropped_warnings(p, starts[empty], (stops - starts)[empty], settle_s)
    rows = np.flatnonzero(keep)
    run_k = run_of_row[rows]
    first = np.concatenate(([True], run_k[1:] != run_k[:-1])) if rows.size else np.zeros(0, bool)
    point_of_row = np.cumsum(first) - 1
    n_points = int(first.sum())
    same = point_of_row[1:] == point_of_row[:-1]
    dt = np.diff(t[rows])[same]
    median_dt = _group_medians(dt, point_of_row[1:][same], n_points)
    with np.errstate(divide="ignore", invalid="ignore"):
        rate = np.where(median_dt > 0, 1.0 / median_dt, 0.0)
    a, b = starts[~empty], stops[~empty]
    first_rows = rows[first]
    command = p.values["command"][a]
    if keys is not None:
        command = np.bincount(point_of_row, p.values["command"][rows]) / np.bincount(point_of_row)
    depth = _depths(p, a, depth_m)
    voltage = _supplies(p, a)
    repeat, direction = _labels(command, depth, voltage)
    samples = {"t_s": t[rows], "command": p.values["command"][rows]}
    samples |= {CHANNELS[k]: p.values[k][rows] for k in CHANNELS if k in p.values}
    bounds = np.concatenate((np.flatnonzero(first), [rows.size]))
    points = ImportedPoints(command, depth, voltage, repeat, direction, t[a], t[first_rows], t[b - 1],
                            np.full(n_points, float(settle_s)), rate, bounds, samples)
    return points, warnings


def _pattern(n: np.ndarray) -> np.ndarray:
    """For points of n[i] samples: values with mean 0 and sample std 1 (alternating signs),
    back to back; a point of one sample gets 0."""
    point = np.repeat(np.arange(n.size), n)
    size = n[point]
    k = np.arange(size.size) - np.concatenate(([0], np.cumsum(n)[:-1]))[point]
    z = np.where(k % 2 == 0, 1.0, -1.0)
    z[(size % 2 == 1) & (k == size - 1)] = 0.0
    even = size % 2 == 0
    z[even] /= np.sqrt(size[even] / (size[even] - 1.0))
    z[size == 1] = 0.0
    return z


def point_steps(p: Parsed, depth_m: float | None) -> tuple[ImportedPoints, list[str]]:
    """One point per row; with std and n columns the point gets n samples of that mean and std.

    Without a time column every row gets t = 0: a table has no time axis, so nothing (a zero
    drift, say) may be fitted against the row order.
    """
    n_rows = p.lines.size
    t = p.values["time"] - p.values["time"][0] if "time" in p.values and n_rows else (
        np.zeros(n_rows))
    std = p.values.get("thrust_std")
    count = p.values.get("n_samples")
    n = np.ones(n_rows, dtype=np.int64)
    if std is not None and count is not None:
        ok = np.isfinite(std) & np.isfinite(count)
        n[ok] = np.clip(count[ok], 1, MAX_SYNTH_SAMPLES).astype(np.int64)
    total = int(n.sum())
    if count is not None and total > MAX_IMPORT_SAMPLES:
        raise UsageError(f"{p.columns['n_samples'].header!r} asks for {total:,} samples in all, "
                         f"more than the {MAX_IMPORT_SAMPLES:,} one import may synthesise")
    row = np.repeat(np.arange(n_rows), n)
    samples = {"t_s": t[row], "command": p.values["command"][row]}
    samples |= {CHANNELS[k]: p.values[k][row] for k in CHANNELS if k in p.values}
    if std is not None:
        spread = n[row] > 1
        samples["thrust_n"][spread] += _pattern(n)[spread] * std[row][spread]
    command = p.values["command"]
    depth = _depths(p, np.arange(n_rows), depth_m)
    voltage = _supplies(p, np.arange(n_rows))
    repeat, direction = _labels(command, depth, voltage)
    zeros = np.zeros(n_rows)
    points = ImportedPoints(command.copy(), depth, voltage, repeat, direction, t, t, t, zeros, zeros,
                            np.concatenate(([0], np.cumsum(n))), samples)
    return points, []
