"""Load one run from the Store into numpy arrays (the only analysis module that reads the Store).

Points, tares and events are read at once; samples are not: `RunData.source` reads them in
blocks of whole points (`PointBlock`), so every stage's memory is bounded by the block, not
the run. Within a block, samples are grouped by point through `offsets`, so stages work
with vectorised per-point reductions instead of per-step queries.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np

from rigtool.errors import DataError, UsageError
from rigtool.store import Store
from rigtool.units import FT_CHANNELS

SAMPLE_FIELDS = ("t_s", "thrust_n", "speed_rpm", "current_a", "voltage_v")
_AXIS_FIT_STEPS = 24  # points sampled to recover the thrust axis from the F/T channels
BLOCK_SAMPLES = 1 << 18  # samples per block of points the analysis reads (whole points)


@dataclass
class Steps:
    """One entry per stored point, ordered by step idx; depth_m is NaN when not set."""

    step_id: np.ndarray
    idx: np.ndarray
    command: np.ndarray
    depth_m: np.ndarray
    repeat: np.ndarray
    direction: np.ndarray
    t_start_s: np.ndarray
    t_acquire_s: np.ndarray
    settled: np.ndarray
    status: np.ndarray
    voltage_v: np.ndarray | None = None  # supply voltage set per point; NaN/None: not swept

    def __len__(self) -> int:
        return len(self.idx)


@dataclass
class Samples:
    """Acquired samples of consecutive points; point p owns rows offsets[p]:offsets[p + 1]
    (time order). A channel not read or not recorded is None."""

    t_s: np.ndarray
    thrust_n: np.ndarray
    speed_rpm: np.ndarray
    current_a: np.ndarray
    point: np.ndarray
    offsets: np.ndarray
    voltage_v: np.ndarray | None = None  # bus voltage (None: not recorded)
    torque_nm: np.ndarray | None = None  # torque about the thrust axis (None: not measured)
    command: np.ndarray | None = None  # command sent with each sample (None: not read)

    def channel(self, name: str) -> np.ndarray:
        """A per-sample channel; `power_w` is V * I sample by sample (so its mean is the mean
        power, not the product of the means); NaN where a channel was not recorded."""
        if name == "power_w":
            return self.channel("voltage_v") * self.current_a * self._current_sign()
        value = getattr(self, name)
        return np.full(self.t_s.shape, np.nan) if value is None else value

    def _current_sign(self) -> np.ndarray:
        """Per sample, the sign of its point's mean current: power is V I with the current
        taken positive for the point as a whole. Folding each sample (|I|) would bias the mean
        power upwards wherever the current noise reaches zero."""
        n_points = self.offsets.size - 1
        total = np.bincount(self.point, weights=np.nan_to_num(self.current_a),
                            minlength=n_points)
        return np.where(total < 0, -1.0, 1.0)[self.point]

    def has(self, name: str) -> bool:
        """Whether a channel was recorded at all (`power_w` needs voltage)."""
        return self.voltage_v is not None if name == "power_w" else (
            getattr(self, name) is not None)


@dataclass
class Tares:
    """Tare events: time (s), six-channel bias, and the bias projected on the thrust axis (N)."""

    t_s: np.ndarray
    bias: np.ndarray
    thrust_bias_n: np.ndarray | None


@dataclass
class RunData:
    """Everything the analysis needs from one run, as arrays."""

    run_id: str
    name: str
    status: str
    command_unit: str
    neutral_command: float
    thruster_id: str | None
    propeller_diameter_m: float | None
    water_density_kg_m3: float | None
    steps: Steps
    source: SampleSource
    tares: Tares
    events: list[dict] = field(default_factory=list)
    step_response: bool = False  # a `command.steps` run: levels follow each other
    # Times (s) at which the run was resumed (`rigtool sweep --resume`): each begins a new
    # session, in which the sensor is opened and tared again (its zero offset starts over).
    session_starts_s: tuple[float, ...] = ()
    # The force sensor's declared accuracy (rig file or `import --sensor-accuracy`): % of full
    # scale per error, and the full scale in N (None: the run's largest thrust).
    sensor_accuracy: dict[str, float | None] | None = None


ACCURACY_KEYS = ("nonlinearity_pct_fs", "hysteresis_pct_fs", "crosstalk_pct_fs")


def sensor_accuracy(rig: dict) -> dict[str, float | None] | None:
    """The declared sensor accuracy of a stored rig (a rig file's `sensor_accuracy`, or an
    import's), checked: each % within 0..100 and the full scale positive (UsageError)."""
    doc = rig.get("sensor_accuracy") or (rig.get("import") or {}).get("sensor_accuracy")
    if not doc:
        return None
    out: dict[str, float | None] = {k: float(doc.get(k) or 0.0) for k in ACCURACY_KEYS}
    if any(not 0.0 <= v <= 100.0 for v in out.values() if v is not None):
        raise UsageError(f"stored sensor_accuracy {doc!r}: each % of full scale must lie in "
                         "0..100")
    fs = doc.get("full_scale_n")
    if fs is not None and not 0.0 < float(fs) <= 1e7:
        raise UsageError(f"stored sensor_accuracy full_scale_n {fs!r} must lie in (0, 1e7] N")
    out["full_scale_n"] = None if fs is None else float(fs)
    return out


def load_run(store: Store, run_id: str) -> RunData:
    """Read run, steps, samples and events of `run_id` into a RunData, all from one
    snapshot of the database (a sweep may still be appending to it)."""
    with store.snapshot():
        return _load_run(store, run_id)


def _load_run(store: Store, run_id: str) -> RunData:
    record = store.run_record(run_id)
    step_rows = store.steps(run_id)
    if not step_rows:
        raise UsageError(f"run {run_id} has no recorded points: nothing to calibrate")
    steps = _steps(step_rows)
    torque = torque_channel(record.rig, store, step_rows)
    events = store.events(run_id)
    tare_rows = [e for e in events if e["kind"] == "tare"]
    tares = _tares(store, tare_rows, steps, step_rows)
    return RunData(
        run_id=run_id,
        name=record.name,
        status=record.status,
        command_unit=record.command_unit,
        neutral_command=record.neutral,
        thruster_id=record.thruster_id,
        propeller_diameter_m=record.propeller_diameter_m,
        water_density_kg_m3=record.water_density_kg_m3,
        steps=steps,
        source=SampleSource(store, run_id, steps, torque),
        tares=tares,
        events=[e for e in events if e["kind"] != "tare"],
        step_response=bool((record.protocol.get("command") or {}).get("steps")),
        session_starts_s=session_starts(events),
        sensor_accuracy=sensor_accuracy(record.rig),
    )


def session_starts(events: list[dict]) -> tuple[float, ...]:
    """The times of a run's resumes (the `resumed` events `rigtool sweep --resume` stores,
    not the engine's retry after a limit trip), in order, each once."""
    times = {float(e["t_s"]) for e in events if e["kind"] == "resumed"
             and "from_idx" in (e.get("detail") or {}) and e.get("t_s") is not None}
    return tuple(sorted(t for t in times if np.isfinite(t)))


def _steps(rows: list[dict]) -> Steps:
    def col(key: str, dtype: type = float) -> np.ndarray:
        return np.array([np.nan if r[key] is None and dtype is float else r[key] for r in rows],
                        dtype=dtype)

    return Steps(
        step_id=col("id", int),
        idx=col("idx", int),
        command=col("command"),
        depth_m=col("depth_m"),
        repeat=col("repeat", int),
        direction=np.array([str(r["direction"]) for r in rows]),
        t_start_s=col("t_start_s"),
        t_acquire_s=col("t_acquire_s"),
        settled=col("settled", bool),
        status=np.array([str(r["status"]) for r in rows]),
        voltage_v=col("voltage_set_v") if rows and "voltage_set_v" in rows[0] else np.full(
            len(rows), np.nan),
    )


def torque_channel(rig: dict, store: Store, step_rows: list[dict]) -> tuple[str, int] | None:
    """The F/T channel that holds torque about the thrust axis, and the thrust sign: `tx`
    for a thrust on `fx`, and so on, when the run's sensor recorded it (a six-axis sensor;
    the stored channels are after the mount transform). None otherwise."""
    axis = (rig.get("resolved") or {}).get("thrust") or rig.get("thrust") or {}
    channel, sign = axis.get("channel"), axis.get("sign", 1)
    if channel not in FT_CHANNELS[:3] or sign not in (1, -1) or not step_rows:
        return None
    name = "t" + channel[1]
    probe = store.iter_step_samples(int(step_rows[-1]["id"]), (name,))
    return (name, int(sign)) if any(np.isfinite(c[name]).any() for c in probe) else None


@dataclass
class PointBlock:
    """The samples of steps rows first_row .. first_row + n_points - 1 (`samples.point` counts
    from 0 at first_row); or a piece of one point longer than a block (`point_n` > 0: the
    point's samples in all, `start`: where in the point the piece begins)."""

    first_row: int
    samples: Samples
    start: int = 0
    point_n: int = 0

    @property
    def piece(self) -> bool:
        """Whether the block is a piece of one long point, not whole points."""
        return self.point_n > 0

    @property
    def last_piece(self) -> bool:
        """Whether the block is the last piece of its long point."""
        return self.piece and self.start + self.samples.t_s.size == self.point_n

    @property
    def rows(self) -> np.ndarray:
        """The steps rows of the block's points, in order."""
        return self.first_row + np.arange(self.samples.offsets.size - 1)


class SampleSource:
    """A run's samples, read from the store block by block of whole points on demand.

    Each block holds about BLOCK_SAMPLES samples, so a pass over the run needs memory for
    one block only. A point longer than that comes as consecutive pieces of at most
    BLOCK_SAMPLES samples (`PointBlock.piece`), which `pieces` reads again for a pass of its
    own. Samples of points not in `steps` (stored after the run was loaded) are skipped."""

    def __init__(self, store: Store, run_id: str, steps: Steps,
                 torque: tuple[str, int] | None = None, batch: int = BLOCK_SAMPLES) -> None:
        self.store, self.run_id, self.steps = store, run_id, steps
        self.torque, self.batch = torque, batch
        self._counts: np.ndarray | None = None

    @property
    def has_torque(self) -> bool:
        """Whether the run recorded torque about the thrust axis."""
        return self.torque is not None

    def sample_count(self) -> int:
        """How many samples the run's points hold in all."""
        return self.store.sample_count(self.run_id)

    def point_counts(self) -> np.ndarray:
        """How many samples each steps row holds (read once)."""
        if self._counts is None:
            stored = self.store.point_sample_counts(self.run_id)
            self._counts = np.array([stored.get(int(i), 0) for i in self.steps.idx], np.int64)
        return self._counts

    def blocks(self, fields: Sequence[str] = (*SAMPLE_FIELDS, "torque_nm")) -> Iterator[PointBlock]:
        """Consecutive blocks of points covering every steps row once, with `fields` read
        (`torque_nm`: the torque channel, sign applied, when recorded); a point longer than
        a block comes in pieces."""
        long = np.flatnonzero(self.point_counts() > self.batch)
        if not long.size:
            yield from self._whole(fields, 0, len(self.steps), bounded=False)
            return
        row = 0
        for at in long.tolist():
            if at > row:
                yield from self._whole(fields, row, at, bounded=True)
            yield from self.pieces(at, fields)
            row = at + 1
        if row < len(self.steps):
            yield from self._whole(fields, row, len(self.steps), bounded=True)

    def pieces(self, row: int, fields: Sequence[str]) -> Iterator[PointBlock]:
        """The samples of steps row `row` in pieces of at most `batch` samples, in order."""
        stored = self._stored(fields)
        n, start = int(self.point_counts()[row]), 0
        for chunk in self.store.iter_samples(self.run_id, tuple(stored.values()),
                                             steps=[int(self.steps.idx[row])],
                                             batch=self.batch):
            size = chunk["step_idx"].size
            for a in range(0, size, self.batch):
                part = {k: v[a:a + self.batch] for k, v in chunk.items()}
                local = np.zeros(part["step_idx"].size, np.int64)
                yield PointBlock(row, _block_samples(part, stored, local, 1, self.torque),
                                 start, n)
                start += local.size

    def _stored(self, fields: Sequence[str]) -> dict[str, str]:
        stored = {f: f for f in fields if f != "torque_nm"}
        if "torque_nm" in fields and self.torque is not None:
            stored["torque_nm"] = self.torque[0]
        return stored

    def _whole(self, fields: Sequence[str], row: int, stop: int,
               bounded: bool) -> Iterator[PointBlock]:
        """Blocks of whole points of steps rows `row` .. `stop` - 1 (`bounded`: read only
        those rows' plan indices; otherwise the whole run, which they are)."""
        stored = self._stored(fields)
        idx = self.steps.idx
        span = (int(idx[row]), int(idx[stop - 1])) if bounded else None
        for chunk in self.store.iter_point_samples(self.run_id, tuple(stored.values()),
                                                   self.batch, span):
            at = _rows_of(idx, chunk["step_idx"])
            known = at >= 0
            if not known.all():
                at = at[known]
                chunk = {k: v[known] for k, v in chunk.items()}
            if not at.size:
                continue
            end = int(at[-1]) + 1
            yield PointBlock(row, _block_samples(chunk, stored, at - row, end - row,
                                                 self.torque))
            row = end
        if row < stop or stop == 0:
            empty = {k: np.empty(0) for k in stored.values()}
            yield PointBlock(row, _block_samples(empty, stored, np.empty(0, np.int64),
                                                 stop - row, self.torque))


def _rows_of(idx: np.ndarray, step_idx: np.ndarray) -> np.ndarray:
    """The steps row of each sample (-1: a point not in `idx`); `step_idx` comes in runs of
    one point, so each run is looked up once."""
    if not step_idx.size or not idx.size:
        return np.full(step_idx.size, -1)
    starts = np.concatenate(([0], np.flatnonzero(np.diff(step_idx)) + 1))
    first = step_idx[starts]
    at = np.minimum(np.searchsorted(idx, first), idx.size - 1)
    at = np.where(idx[at] == first, at, -1)
    return np.repeat(at, np.diff(np.append(starts, step_idx.size)))


def _block_samples(chunk: dict[str, np.ndarray], stored: dict[str, str], point: np.ndarray,
                   n_points: int, torque: tuple[str, int] | None) -> Samples:
    """One chunk of whole points (`point`: local row of each sample, ascending) as Samples."""
    arrays: dict[str, np.ndarray | None] = {k: chunk[c] for k, c in stored.items()}
    if torque is not None and arrays.get("torque_nm") is not None and torque[1] < 0:
        np.negative(arrays["torque_nm"], out=arrays["torque_nm"])
    arrays.setdefault("t_s", np.empty(0))
    for name in ("thrust_n", "speed_rpm", "current_a"):
        arrays.setdefault(name, None)
    counts = np.bincount(point, minlength=n_points)
    offsets = np.concatenate(([0], np.cumsum(counts)))
    return Samples(point=point, offsets=offsets, **arrays)  # type: ignore[arg-type]


def _tares(store: Store, rows: list[dict], steps: Steps, step_rows: list[dict]) -> Tares:
    t = np.array([np.nan if r["t_s"] is None else r["t_s"] for r in rows], dtype=float)
    bias = np.full((len(rows), 6), np.nan)
    for i, r in enumerate(rows):
        values = (r["detail"] or {}).get("bias") or []
        for j, v in enumerate(values[:6]):
            bias[i, j] = np.nan if v is None else float(v)
    keep = np.isfinite(t)
    t, bias = t[keep], bias[keep]
    thrust_bias = None
    if len(t):
        weights = _thrust_axis(store, step_rows, np.isfinite(bias).any(axis=0))
        if weights is not None:
            thrust_bias = np.nan_to_num(bias) @ weights
    return Tares(t_s=t, bias=bias, thrust_bias_n=thrust_bias)


def _thrust_axis(store: Store, step_rows: list[dict], usable: np.ndarray) -> np.ndarray | None:
    """Weights w with thrust_n ~ w . (fx..tz) + c, by least squares on a few spread-out points.

    The rig file's axis convention is not needed: the stored thrust and F/T channels define it.
    The points are read one at a time (twice: which channels hold data, then the fit), a
    point longer than BLOCK_SAMPLES one stored block at a time, and the least squares problem
    is reduced to its triangular factor as they come, so memory is bounded by a block.
    """
    rows = sorted((r for r in step_rows if r["thrust_all_mean_n"] is not None),
                  key=lambda r: r["thrust_all_mean_n"])
    if not rows or not usable.any():
        return None
    pick = np.unique(np.linspace(0, len(rows) - 1, min(_AXIS_FIT_STEPS, len(rows))).astype(int))
    ids = [(int(rows[i]["id"]), int(rows[i]["n"] or 0)) for i in pick]

    def points() -> Iterator[np.ndarray]:
        for i, n in ids:  # a point up to a block at once, a longer one a stored block at a time
            batch = BLOCK_SAMPLES if n <= BLOCK_SAMPLES else 1
            for part in store.iter_step_samples(i, (*FT_CHANNELS, "thrust_n"), batch):
                yield np.column_stack(list(part.values())).reshape(-1, 7)

    finite, n_rows = np.ones(6, bool), 0
    for data in points():
        finite &= np.isfinite(data[:, :6]).all(axis=0)
        n_rows += data.shape[0]
    if n_rows == 0:
        return None
    cols = np.flatnonzero(usable & finite)
    if cols.size == 0:
        return None
    factor, n_ok = np.empty((0, cols.size + 2)), 0
    for data in points():
        ok = np.isfinite(data[:, 6]) & np.isfinite(data[:, cols]).all(axis=1)
        rows_ok = np.column_stack([data[ok][:, cols], np.ones(ok.sum()), data[ok, 6]])
        factor = np.linalg.qr(np.vstack([factor, rows_ok]), mode="r")
        n_ok += int(ok.sum())
    if n_ok <= cols.size + 1:
        return None
    # The cut-off lstsq takes by default for the whole (n_ok x k) problem, not the factor's.
    rcond = np.finfo(float).eps * max(n_ok, cols.size + 1)
    coef, *_ = np.linalg.lstsq(factor[:, :-1], factor[:, -1], rcond=rcond)
    weights = np.zeros(6)
    weights[cols] = coef[:-1]
    return weights


@dataclass
class CaptiveData:
    """A captive run's points: the flow each was held in and its six F/T channels' samples
    (point p owns rows offsets[p]:offsets[p + 1] of `ft`, shape (n, 6), in the rig's frame)."""

    run_id: str
    angle: str  # "yaw" or "attack"
    step_idx: np.ndarray
    speed_mps: np.ndarray  # as the carriage reported it (the target where it reported none)
    angle_deg: np.ndarray
    t_s: np.ndarray  # each point's mean sample time (acquisition order)
    ft: np.ndarray
    offsets: np.ndarray


def _flow_of(run_id: str, store: Store, field_name: str, value: object, bound: float) -> float:
    """A stored speed or angle, checked finite and within `bound` (DataError otherwise)."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not (
            np.isfinite(value) and abs(value) <= bound):
        raise DataError(f"{store.path}: run {run_id}: {field_name} is {value!r}, not a number "
                        f"within +-{bound:g}")
    return float(value)


def load_captive(store: Store, run_id: str) -> CaptiveData | None:
    """The captive part of a run (None when its protocol has no `captive:` axis): each stored
    point's flow from the plan and the carriage's `captive` events, and its F/T samples."""
    run = store.run(run_id)
    captive = (run.get("protocol") or {}).get("captive")
    if not captive:
        return None
    kind = captive.get("angle", "yaw") if isinstance(captive, dict) else None
    if kind not in ("yaw", "attack"):
        raise DataError(f"{store.path}: run {run_id}: protocol.captive.angle is {kind!r}, not "
                        "'yaw' or 'attack'")
    plan = {s.get("idx"): s for s in run.get("plan") or [] if isinstance(s, dict)}
    reached: dict[int, float] = {}
    for e in store.events(run_id, "captive"):
        value = (e.get("detail") or {}).get("reached_mps")
        if value is not None and e.get("step_idx") is not None:
            reached[int(e["step_idx"])] = _flow_of(run_id, store, "reached_mps", value, 1e3)
    idx, speed, angle, t_mid, parts, counts = [], [], [], [], [], []
    current: tuple[float, float, float] | None = None  # last reported: target, angle, reached
    for chunk in store.iter_point_samples(run_id, ("t_s", *FT_CHANNELS)):
        for i in np.unique(chunk["step_idx"]):
            step = plan.get(int(i)) or {}
            target = _flow_of(run_id, store, f"plan[{i}].speed_mps", step.get("speed_mps"), 1e3)
            deg = _flow_of(run_id, store, f"plan[{i}].angle_deg", step.get("angle_deg"), 180.0)
            if int(i) in reached:
                current = (target, deg, reached[int(i)])
            rows = chunk["step_idx"] == i
            idx.append(int(i))
            speed.append(current[2] if current and current[:2] == (target, deg) else target)
            angle.append(deg)
            t_mid.append(float(np.mean(chunk["t_s"][rows])))
            parts.append(np.column_stack([chunk[c][rows] for c in FT_CHANNELS]))
            counts.append(int(rows.sum()))
    if not idx:
        raise UsageError(f"run {run_id} has no recorded points: nothing to calibrate")
    return CaptiveData(run_id, kind, np.array(idx),
                       np.array(speed), np.array(angle), np.array(t_mid),
                       np.concatenate(parts), np.concatenate(([0], np.cumsum(counts))))
