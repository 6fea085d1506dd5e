"""Group parsed rows into points: a time series by runs of equal command, a table row by row."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rigtool.importers.generic import Parsed

CHANNELS = {"thrust": "thrust_n", "speed": "speed_rpm", "current": "current_a",
            "voltage": "voltage_v"}
MAX_SYNTH_SAMPLES = 10_000
TIMESERIES_MIN_RUN = 3  # median rows per command above which `auto` reads a time series


@dataclass
class ImportedStep:
    """One point of the imported run: its command and the samples that belong to it."""

    command: float
    depth_m: float | None
    repeat: int
    direction: str
    t_start_s: float
    t_acquire_s: float
    t_end_s: float
    settle_s: float
    rate_hz: float
    samples: dict[str, np.ndarray]


def _runs(keys: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of consecutive rows with equal keys."""
    if keys.size == 0:
        return []
    change = np.flatnonzero(np.any(keys[1:] != keys[:-1], axis=1)) + 1
    edges = np.concatenate(([0], change, [keys.shape[0]]))
    return list(zip(edges[:-1].tolist(), edges[1:].tolist(), strict=True))


def _keys(p: Parsed, depth_m: float | None) -> np.ndarray:
    cmd = p.values["command"]
    depth = p.values.get("depth", np.full(cmd.size, np.nan if depth_m is None else depth_m))
    return np.column_stack([cmd, np.nan_to_num(depth, nan=-1e300)])


def choose_format(p: Parsed, requested: str, depth_m: float | None) -> str:
    """`points` for per-point tables, `timeseries` for logs holding each command for many rows."""
    if requested != "auto":
        return requested
    if "thrust_std" in p.values or "n_samples" in p.values or "time" not in p.values:
        return "points"
    lengths = [b - a for a, b in _runs(_keys(p, depth_m))]
    return "timeseries" if lengths and np.median(lengths) >= TIMESERIES_MIN_RUN else "points"


def _depth(p: Parsed, i: int, depth_m: float | None) -> float | None:
    d = p.values.get("depth")
    if d is not None and np.isfinite(d[i]):
        return float(d[i])
    return depth_m


class _Labeller:
    """Repeat index per (command, depth) and sweep direction from the previous command."""

    def __init__(self) -> None:
        self.seen: dict[tuple, int] = {}
        self.previous: float | None = None

    def __call__(self, command: float, depth: float | None) -> tuple[int, str]:
        key = (command, depth)
        self.seen[key] = self.seen.get(key, 0) + 1
        direction = "down" if self.previous is not None and command < self.previous else "up"
        self.previous = command
        return self.seen[key], direction


def timeseries_steps(p: Parsed, settle_s: float, depth_m: float | None) -> tuple[
        list[ImportedStep], list[str]]:
    """One point per run of equal command; the first `settle_s` of each run is dropped."""
    t = p.values["time"]
    t = t - t[0] if t.size else t
    warnings = []
    if t.size > 1 and np.any(np.diff(t) < 0):
        warnings.append("time column goes backwards: rows are kept in file order")
    steps, label = [], _Labeller()
    for a, b in _runs(_keys(p, depth_m)):
        keep = np.arange(a, b)[t[a:b] >= t[a] + settle_s]
        cmd = float(p.values["command"][a])
        if keep.size == 0:
            warnings.append(f"command {cmd:g} at line {p.lines[a]}: all {b - a} row(s) inside "
                            f"the {settle_s:g} s settling time; point dropped")
            continue
        dt = np.diff(t[keep])
        rate = float(1.0 / np.median(dt)) if dt.size and np.median(dt) > 0 else 0.0
        depth = _depth(p, a, depth_m)
        repeat, direction = label(cmd, depth)
        samples = {"t_s": t[keep], "command": np.full(keep.size, cmd)}
        samples |= {CHANNELS[k]: p.values[k][keep] for k in CHANNELS if k in p.values}
        steps.append(ImportedStep(cmd, depth, repeat, direction, float(t[a]), float(t[keep[0]]),
                                  float(t[b - 1]), settle_s, rate, samples))
    return steps, warnings


def _pattern(n: int) -> np.ndarray:
    """n values with mean 0 and sample standard deviation 1 (alternating signs)."""
    z = np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
    if n % 2:
        z[-1] = 0.0
    return z / np.std(z, ddof=1)


def point_steps(p: Parsed, depth_m: float | None) -> tuple[list[ImportedStep], list[str]]:
    """One point per row; with std and n columns the point gets n samples of that mean and std.

    Without a time column every row gets t = 0: a table has no time axis, so nothing (a zero
    drift, say) may be fitted against the row order.
    """
    n_rows = p.lines.size
    t = p.values["time"] - p.values["time"][0] if "time" in p.values and n_rows else (
        np.zeros(n_rows))
    std = p.values.get("thrust_std")
    count = p.values.get("n_samples")
    steps, label = [], _Labeller()
    for i in range(n_rows):
        cmd = float(p.values["command"][i])
        n = 1
        if std is not None and count is not None and np.isfinite(std[i]) and np.isfinite(count[i]):
            n = int(min(max(count[i], 1), MAX_SYNTH_SAMPLES))
        z = _pattern(n) * std[i] if n > 1 else np.zeros(1)
        samples = {"t_s": np.full(n, t[i]), "command": np.full(n, cmd)}
        samples |= {CHANNELS[k]: np.full(n, p.values[k][i]) for k in CHANNELS if k in p.values}
        samples["thrust_n"] = samples["thrust_n"] + z
        depth = _depth(p, i, depth_m)
        repeat, direction = label(cmd, depth)
        steps.append(ImportedStep(cmd, depth, repeat, direction, float(t[i]), float(t[i]),
                                  float(t[i]), 0.0, 0.0, samples))
    return steps, []
