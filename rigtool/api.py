"""rigtool as a library: runs, points, samples and calibrations for notebooks (docs/api.md).

    lab = rigtool.open("rigtool.sqlite")
    run = lab.run("last")
    run.points()["thrust_all_mean_n"]
    cal = rigtool.load_calibration("calibrations/<run-id>")
    cal.command(20.0)

Column names are those of points.csv and of `rigtool export`. Arrays are numpy; every table
has `.to_pandas()` when pandas is installed.
"""

from __future__ import annotations

import contextlib
import math
import os
from collections import Counter
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rigtool import display, vehicle_workflow
from rigtool.analysis.vehicle.identify import METHODS, Identification
from rigtool.artefacts.hydro_formats import HydroOptions
from rigtool.dbpath import DB_ENV, DEFAULT_DB
from rigtool.errors import UsageError
from rigtool.files import decode_utf8, read_regular_bytes
from rigtool.models import laws
from rigtool.models.thrust_map import STATUS_KEYS, ThrustMap, thrust_map
from rigtool.progress_hook import ProgressHook, no_progress
from rigtool.readback import MAX_JSON_BYTES, Invalid, calibration_document, parse_json, show
from rigtool.sections import deepest_depth, middle_voltage
from rigtool.store import RunRecord, Store
from rigtool.vehicle_file import Vehicle, load_vehicle
from rigtool.vehicle_workflow import ThrusterInput

__all__ = ["Calibration", "Columns", "ConsumerModel", "Lab", "Records", "Run", "StepDynamics",
           "Value", "identify_vehicle", "load_calibration", "open", "vehicle_thrusters"]

CALIBRATION_FILE = "calibration.json"
CURVE_FILE = "command_curve.csv"
LUT_FILE = "inverse_lut.csv"
CURVE_NEEDS = ("depth_m", "command", "thrust_fit_n")  # columns load_calibration reads
LUT_NEEDS = ("depth_m", "branch", "direction", "thrust_n", "command")
MAX_CSV_BYTES = 32 << 20  # a calibration CSV (real ones: a few kB per depth)
MAX_CSV_ROWS = 500_000
MAX_CSV_COLUMNS = 64  # real ones have 6 or 13
PANDAS_HINT = ("pip install pandas (or, in a clone of rigtool, pip install -e '.[pandas]'; "
               "`rigtool[pandas]` resolves only where rigtool comes from a package index)")
LAB_RUNS_SHOWN = 10  # runs a lab's notebook display lists
COEFFICIENTS_SHOWN = 40  # from each end of a calibration's coefficients (real ones: about 30)


class Columns(dict):
    """Column name -> numpy array, all of one length."""

    def __repr__(self) -> str:
        return display.columns_repr("table", self)

    def _repr_html_(self) -> str:
        return display.columns_html("rigtool table", self)

    def to_pandas(self) -> Any:
        """A pandas DataFrame of the columns (needs pandas)."""
        return _pandas().DataFrame(dict(self))


class Records(list):
    """A list of dicts, one per row."""

    def __repr__(self) -> str:
        return display.records_repr("records", self)

    def _repr_html_(self) -> str:
        return display.records_html("rigtool records", self)

    def to_pandas(self) -> Any:
        """A pandas DataFrame, one row per record (needs pandas)."""
        return _pandas().DataFrame.from_records(list(self))


def _pandas() -> Any:
    try:
        import pandas
    except ImportError as exc:
        raise ImportError(f"to_pandas() needs pandas: {PANDAS_HINT}") from exc
    return pandas


def open(path: str | os.PathLike[str] | None = None, *, write: bool = False) -> Lab:  # noqa: A001
    """The run database at `path` (default: $RIGTOOL_DB, else ./rigtool.sqlite).

    Read-only unless `write` is true (then `Lab.calibrate` may store its results)."""
    target = Path(path or os.environ.get(DB_ENV) or DEFAULT_DB)
    if not target.exists():
        raise UsageError(f"no run database at {target}")
    return Lab(Store(target, read_only=not write, create=False))


def load_calibration(folder: str | os.PathLike[str]) -> Calibration:
    """The calibration `rigtool calibrate` wrote to `folder` (calibrations/<run-id>/)."""
    root = Path(folder)
    doc_path = root / CALIBRATION_FILE
    if not doc_path.is_file():
        raise UsageError(f"{root}: no {CALIBRATION_FILE} here (a calibrations/<run-id>/ folder "
                         "written by `rigtool calibrate`)")
    document = _read_document(doc_path)
    curve, lut = _read_csv(root / CURVE_FILE, CURVE_NEEDS), _read_csv(root / LUT_FILE, LUT_NEEDS)
    try:
        return Calibration(document, curve, lut)
    except UsageError as exc:
        raise UsageError(f"{doc_path}: {exc}") from None


def _read_document(path: Path) -> dict:
    """calibration.json, size-capped, parsed with bounds and checked; UsageError names the field."""
    data = read_regular_bytes(path, MAX_JSON_BYTES)
    try:
        return calibration_document(parse_json(data))
    except Invalid as exc:
        raise UsageError(f"{path}: {exc}") from None


class Lab:
    """A run database. Use as a context manager, or call close()."""

    def __init__(self, store: Store) -> None:
        self.store = store
        self.path = store.path

    def __enter__(self) -> Lab:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<rigtool lab {self.path}>"

    def _repr_html_(self) -> str:
        runs = self.store.runs(limit=LAB_RUNS_SHOWN)
        return display.fields_html(
            f"rigtool lab {Path(self.path).name}",
            [("database", self.path), ("mode", "read-only" if self.store.read_only else "write")],
            display.records_html(f"newest runs (up to {LAB_RUNS_SHOWN})", runs))

    def close(self) -> None:
        """Close the database; closing twice is harmless."""
        self.store.close()

    @contextlib.contextmanager
    def snapshot(self) -> Iterator[Lab]:
        """Read one state of the database: every call inside the block, on this lab and its
        runs, sees the database as it was at the first read, even while a sweep appends
        points. A nested block joins the outer one; the outermost ends the snapshot when it
        exits, also on an exception."""
        with self.store.snapshot():
            yield self

    def runs(self, limit: int = 1000) -> Records:
        """The runs, newest first: id, name, status, created_utc, n_planned, command_unit,
        n_steps."""
        return Records(self.store.runs(limit=limit))

    def run(self, ref: str) -> Run:
        """A run by full id, unique id prefix or "last"."""
        return Run(self.store, self.store.run_record(self.store.resolve_run_id(ref)))

    def calibration(self, run: Run | str) -> Calibration:
        """What `rigtool calibrate` stored for a run (UsageError when it was never calibrated)."""
        from rigtool.workflows import stored_results

        run_id = run.id if isinstance(run, Run) else self.store.resolve_run_id(run)
        results = stored_results(self.store, run_id)
        if results.calibration is None:
            raise UsageError(f"run {run_id} has no points: there is no calibration")
        return Calibration.from_results(results.calibration, results.created_utc)

    def calibrate(self, run: Run | str, out_dir: str | os.PathLike[str] = "calibrations",
                  **options: Any) -> Calibration:
        """Run `rigtool calibrate` on a run (needs `open(..., write=True)`); options as the
        CLI's: base=, causal=, train_with=."""
        from rigtool.workflows import calibrate

        if self.store.read_only:
            raise UsageError(f"{self.path} is open read-only: use rigtool.open(path, write=True) "
                             "to calibrate")
        if self.store.in_snapshot:
            raise UsageError("calibrate writes to the database: call it outside lab.snapshot()")
        ref = run.id if isinstance(run, Run) else run
        results = calibrate(self.store, ref, out_dir, **options)
        return Calibration.from_results(results.calibration, results.created_utc)


class Run:
    """One stored run: its record, points, samples and events."""

    def __init__(self, store: Store, record: RunRecord) -> None:
        self._store = store
        self.record = record
        self.id = record.id
        self.name = record.name
        self.status = record.status
        self.metadata = record.metadata
        self.protocol = record.protocol
        self.rig = record.rig
        self.command_unit = record.command_unit
        self.neutral = record.neutral
        self.thruster_id = record.thruster_id

    def __repr__(self) -> str:
        return f"<rigtool run {self.id} {self.name!r} {self.status}>"

    def _repr_html_(self) -> str:
        r = self.record
        return display.fields_html(f"rigtool run {r.name}", [
            ("id", r.id), ("status", r.status), ("created (UTC)", r.created_utc),
            ("finished (UTC)", r.finished_utc or "-"), ("stop reason", r.stop_reason or "-"),
            ("thruster", r.thruster_id or "-"), ("command unit", r.command_unit),
            ("points planned", r.n_planned), ("rig", r.rig_name or "-")])

    def points(self) -> Columns:
        """One row per stored point: step_idx, command, depth_m, voltage_set_v, ...,
        thrust_all_mean_n, ...
        (statistics over all of the point's samples; points.csv has the steady window's)."""
        return Columns(self._store.points(self.id))

    def samples(self, steps: Iterable[int] | None = None,
                columns: Iterable[str] | None = None) -> Columns:
        """Samples of the run, or of the points whose plan index is in `steps`: t_s,
        thrust_n, ..., step_idx and seq as int (-1 where unrecorded)."""
        return Columns(self._store.sample_arrays(self.id, columns, steps))

    def events(self, kind: str | None = None) -> Records:
        """Events (tares, limit trips, warnings, ventilation...): kind, t_s, step_idx, detail."""
        return Records({"kind": e["kind"], "t_s": e["t_s"], "step_idx": e["step_idx"],
                        "detail": e["detail"]} for e in self._store.events(self.id, kind))


@dataclass(frozen=True)
class Value:
    """A coefficient with its 95 % interval lo..hi (NaN where it has none); the spelling of
    the analysis results and of calibration.json."""

    name: str
    value: float
    lo: float
    hi: float
    unit: str
    n: int = 0
    r2: float = math.nan

    def __repr__(self) -> str:
        return f"<rigtool value {self.name} = {self}>"

    def __str__(self) -> str:
        return display.interval_text(self.value, self.lo, self.hi, self.unit)

    def _repr_html_(self) -> str:
        return f"<code>{display.escaped(self.name)} = {display.escaped(str(self))}</code>"

    @property
    def low(self) -> float:
        """`lo` under the name docs/api.md gave it first (kept readable)."""
        return self.lo

    @property
    def high(self) -> float:
        """`hi` under the name docs/api.md gave it first (kept readable)."""
        return self.hi


@dataclass(frozen=True)
class ConsumerModel:
    """A simpler model exported for consumers that take only it (first-order, rise-fall,
    yoerger; calibration.json `dynamics.consumers`): its parameters, its RMS deviation from
    the selected model over the step run, and whether that is within the limit."""

    name: str
    equation: str
    parameters: dict[str, Value]
    error_n: float
    error_frac: float
    adequate: bool


class StepDynamics:
    """The identified dynamics (calibration.json `dynamics`): the selected model's
    parameters as Values, the simpler models for consumers, and a simulation from a command
    time series."""

    def __init__(self, document: dict) -> None:
        self.document = document
        self.selected: str = document["selected"]
        self.identified: bool = bool(document.get("identified", True))
        self.reason: str = str(document.get("reason", ""))  # why not identified
        model = document["models"][self.selected]
        self.parameters: dict[str, Value] = {
            k: _coefficient_value(k, v) for k, v in model.items() if isinstance(v, dict)}
        self.levels = {float(x["command"]): _float(x["thrust_n"]) for x in document["levels"]}
        self.time_constant_s: float = _number(document.get("time_constant_s"))
        self.first_order_time_constant_s: float = _number(
            document.get("first_order_time_constant_s"))
        self.rise_time_constant_s: float = _number(document.get("rise_time_constant_s"))
        self.fall_time_constant_s: float = _number(document.get("fall_time_constant_s"))
        found = document.get("consumers")
        self.consumers: dict[str, ConsumerModel] = {
            name: _consumer(name, c) for name, c in (found or {}).items()
            if isinstance(found, dict) and isinstance(c, dict)}

    def __repr__(self) -> str:
        if not self.identified:
            return f"<rigtool dynamics: none identified ({self.reason})>"
        p = self.parameters
        lag = p.get("tau_n") or p.get("alpha")
        return f"<rigtool dynamics: {self.selected}, {lag.name} {lag.value:.3g}>" if lag else (
            f"<rigtool dynamics: {self.selected}>")

    def simulate(self, t_s: Any, command: Any, steady: Any = None) -> np.ndarray:
        """Thrust (N) for commands `command[i]` held from `t_s[i]`, with the selected model
        (direction-dependent steady map included). `steady` maps a command to its steady
        thrust (a steady sweep's `cal.thrust` is best); by default the levels of the step
        run, interpolated in speed."""
        from rigtool.analysis.dynamics import simulate_document

        return simulate_document(self.document, np.asarray(t_s, dtype=float),
                                 np.asarray(command, dtype=float), steady)


@dataclass
class _Depth:
    """One depth's curve (command -> thrust) and inverse table (thrust -> command)."""

    depth_m: float | None
    voltage_v: float | None  # supply voltage set (None: not swept)
    coefficients: dict[str, Value]
    curve_command: np.ndarray
    curve_thrust: np.ndarray
    lut: list[tuple[str, np.ndarray, np.ndarray]]  # (direction, thrust ascending, command)
    thrust_law: dict[str, dict]  # per direction ("fwd"/"rev"): family and params


class Calibration:
    """A calibration as `rigtool calibrate` wrote it: coefficients and the curves that map
    command <-> thrust. Without `depth`, methods use the deepest depth (the thruster's own
    thrust: shallower points may ventilate); pass `depth` to pick another. A run swept over
    supply voltages has a section per voltage: without `voltage`, methods use the middle
    voltage of the sweep; pass `voltage` (V, one of `voltages`) to pick another."""

    def __init__(self, document: dict, curve: Columns, lut: Columns) -> None:
        self.document = document
        source = document.get("source") or {}
        self.run_id: str = source.get("run_id", "")
        self.command_unit: str = source.get("command_unit", "")
        self.neutral: float = _float(source.get("neutral_command"))
        self.warnings: list[str] = list(document.get("warnings") or [])
        self._depths = [_depth_from(d, curve, lut) for d in document.get("depths") or []]
        if not self._depths:
            raise UsageError(f"calibration of run {self.run_id} has no depth sections")

    @classmethod
    def from_results(cls, cal: Any, created_utc: str) -> Calibration:
        """From the analysis results (the same rows calibrate writes to the CSV files)."""
        from rigtool.artefacts.calibration import (
            CURVE_COLUMNS,
            LUT_COLUMNS,
            calibration_document,
            curve_rows,
            lut_rows,
        )

        return cls(calibration_document(cal, created_utc),
                   _columns([c[0] for c in CURVE_COLUMNS], curve_rows(cal)),
                   _columns([c[0] for c in LUT_COLUMNS], lut_rows(cal)))

    def __repr__(self) -> str:
        return f"<rigtool calibration of run {self.run_id}, depths {self.depths}>"

    def _repr_html_(self) -> str:
        coefficients = [{"coefficient": v.name, "value": v.value, "95 % low": v.lo,
                         "95 % high": v.hi, "unit": v.unit, "n": v.n}
                        for v in self.coefficients.values()]
        dynamics = self.dynamics
        source = self.document.get("source") or {}
        return display.fields_html(f"rigtool calibration of run {self.run_id}", [
            ("thruster", source.get("thruster_id") or "-"), ("command unit", self.command_unit),
            ("depths (m)", ", ".join("not set" if d is None else f"{d:g}" for d in self.depths)),
            ("supply voltages (V)", ", ".join(f"{v:g}" for v in self.voltages) or "-"),
            ("dynamics", "-" if dynamics is None else repr(dynamics)),
            ("warnings", len(self.warnings))],
            display.records_html("coefficients of the deepest section", coefficients,
                                 head=COEFFICIENTS_SHOWN))

    @property
    def depths(self) -> list[float | None]:
        """Depths (m) with a section, in the calibration's order (None: depth not set)."""
        return [d.depth_m for d in self._depths]

    @property
    def voltages(self) -> list[float]:
        """Supply voltages (V) the run was swept at, ascending (empty: not swept)."""
        return sorted({d.voltage_v for d in self._depths if d.voltage_v is not None})

    @property
    def dynamics(self) -> StepDynamics | None:
        """The thruster dynamics of a step-response run (None for a steady sweep)."""
        doc = self.document.get("dynamics")
        return None if doc is None else StepDynamics(doc)

    @property
    def voltage_laws(self) -> list[dict]:
        """Per depth, the fitted C_n(U) = k U^b with its per-voltage coefficients, as in
        calibration.json `voltage_laws`."""
        return list(self.document.get("voltage_laws") or [])

    @property
    def coefficients(self) -> dict[str, Value]:
        """Coefficients of the deepest depth: C_p_fwd, C_p_rev, C_n, I_0, C_i_fwd, ..."""
        return self._at(None).coefficients

    def coefficients_at(self, depth: float | None, voltage: float | None = None
                        ) -> dict[str, Value]:
        """Coefficients of the section at `depth` (m) and supply `voltage` (V)."""
        return self._at(depth, voltage).coefficients

    def current_coefficient(self, voltage: Any, depth: float | None = None) -> Any:
        """C_n (A/(r/min)^3) at supply voltage U from the fitted law k U^b. Vectorised."""
        d = self._at(depth)
        law = next((w for w in self.voltage_laws if w.get("depth_m") == d.depth_m), None)
        if law is None:
            raise ValueError(f"run {self.run_id} was not swept over supply voltages"
                             + ("" if d.depth_m is None else f" at {d.depth_m:g} m"))
        u = np.asarray(voltage, dtype=float)
        return _like(voltage, _float(law["k"].get("value")) * u ** _float(law["b"].get("value")))

    def thrust(self, command: Any, depth: float | None = None,
               voltage: float | None = None) -> Any:
        """Thrust (N) at `command` from the command curve: 0 in dead zones, NaN outside the
        commands measured. Vectorised; a scalar in gives a scalar out."""
        d = self._at(depth, voltage)
        c = np.asarray(command, dtype=float)
        if d.curve_command.size == 0:
            return _like(command, np.full(c.shape, np.nan))
        f = np.interp(c, d.curve_command, d.curve_thrust)
        inside = (c >= d.curve_command[0]) & (c <= d.curve_command[-1])
        return _like(command, np.where(inside, f, np.nan))

    def command(self, thrust: Any, depth: float | None = None,
                voltage: float | None = None, *, strict: bool = False) -> Any:
        """The command giving `thrust` (N), as a vehicle needs it: the inverse lookup table;
        the neutral command for 0 and below the smallest thrust the thruster makes; beyond the
        largest, that direction's extreme command; NaN only for NaN. `strict=True`: NaN
        outside the table instead (`command_status` says which case). Vectorised."""
        out, _ = self.thrust_map(depth, voltage).command(thrust, strict=strict)
        return _like(thrust, out)

    def command_status(self, thrust: Any, depth: float | None = None,
                       voltage: float | None = None) -> Any:
        """Why `command` gives what it gives, per thrust: "ok", "clamped" (beyond the largest
        thrust), "below_min" (neutral), "gap" (between branches: nearer end) or "nan"."""
        _, status = self.thrust_map(depth, voltage).command(thrust)
        names = np.array([STATUS_KEYS[int(s)] for s in status.ravel()]).reshape(status.shape)
        return str(names) if np.ndim(thrust) == 0 else names

    def thrust_map(self, depth: float | None = None, voltage: float | None = None
                   ) -> ThrustMap:
        """The thrust -> command map of a section (rigtool.models.thrust_map)."""
        d = self._at(depth, voltage)
        return thrust_map(d.lut, self.neutral, d.curve_command, d.curve_thrust)

    def thrust_from_speed(self, speed_rpm: Any, depth: float | None = None,
                          voltage: float | None = None) -> Any:
        """Thrust (N) from propeller speed (r/min) by the law calibrate chose per direction
        (`thrust_law`: f = C_p n^2, C_p n^2 + C_l n or C n^k, signed like n), else
        f = C_p |n| n with C_p_fwd for n > 0 and C_p_rev for n < 0 (NaN where that direction
        was not fitted)."""
        here = self._at(depth, voltage)
        fwd, rev = (_value(here.coefficients, k) for k in ("C_p_fwd", "C_p_rev"))
        n = np.asarray(speed_rpm, dtype=float)
        out = laws.thrust_from_speed(n, fwd, rev)
        for key, sign in (("fwd", 1.0), ("rev", -1.0)):
            law = here.thrust_law.get(key)
            if law is not None and law["family"] != "quadratic":
                side = np.sign(n) == sign
                out = np.where(side, sign * laws.thrust_law(law["family"], law["params"], n),
                               out)
        return _like(speed_rpm, out)

    def thrust_from_current(self, current_a: Any, direction: str = "forward",
                            depth: float | None = None, voltage: float | None = None) -> Any:
        """Thrust (N) from motor current (A): f = C_i (|I| - I_0)^(2/k), k = 3 unless the free
        current law replaced it (`current_exponent`), signed by `direction` ("forward" or
        "reverse"; current alone cannot tell). Uses the directly
        fitted C_i where there is one, else C_p / C_n^(2/3). With `voltage`, the section
        swept at that supply voltage."""
        if direction not in ("forward", "reverse"):
            raise ValueError(f"direction must be 'forward' or 'reverse', not {direction!r}")
        coef = self._at(depth, voltage).coefficients
        key = "fwd" if direction == "forward" else "rev"
        c_i = _value(coef, f"C_i_{key}_direct")
        if math.isnan(c_i):
            c_i = _value(coef, f"C_i_{key}")
        k = _value(coef, "current_exponent")  # the free current law, where it replaced k = 3
        i_0 = _value(coef, "I_0" if math.isnan(k) else "I_0_free")
        i_0 = 0.0 if math.isnan(i_0) else i_0
        f = laws.thrust_from_current(current_a, c_i, i_0,
                                     laws.CURRENT_EXPONENT if math.isnan(k) else k)
        return _like(current_a, f if direction == "forward" else -f)

    def _at(self, depth: float | None, voltage: float | None = None) -> _Depth:
        if depth is None:
            depth_m = deepest_depth(self.depths)
        else:
            depth_m = next((d.depth_m for d in self._depths
                            if d.depth_m is not None and abs(d.depth_m - depth) < 1e-6), None)
            if depth_m is None:
                have = ", ".join("not set" if d is None else f"{d:g} m"
                                 for d in dict.fromkeys(self.depths))
                raise ValueError(f"no section at depth {depth:g} m; this calibration has {have}")
        here = [d for d in self._depths if d.depth_m == depth_m]
        if voltage is None:
            return here[middle_voltage([d.voltage_v for d in here])]
        for d in here:
            if d.voltage_v is not None and abs(d.voltage_v - voltage) < 1e-6:
                return d
        raise ValueError(f"no section at {voltage:g} V; this calibration was swept at "
                         f"{', '.join(f'{v:g} V' for v in self.voltages) or 'no voltages'}")


def _depth_from(doc: dict, curve: Columns, lut: Columns) -> _Depth:
    depth, volts = doc.get("depth_m"), doc.get("supply_voltage_v")

    def mine(table: Columns) -> np.ndarray:
        if not table:
            return np.zeros(0, dtype=bool)
        d = table["depth_m"]
        at = np.isnan(d) if depth is None else np.abs(d - depth) < 1e-6
        v = table.get("voltage_set_v")  # absent in files written before voltage sweeps
        if v is None:
            return at
        return at & (np.isnan(v) if volts is None else np.abs(v - volts) < 1e-6)

    m = mine(curve)
    order = np.argsort(curve["command"][m]) if m.any() else np.zeros(0, dtype=int)
    cmd = curve["command"][m][order] if m.any() else np.zeros(0)
    fit = curve["thrust_fit_n"][m][order] if m.any() else np.zeros(0)
    ok = np.isfinite(fit)
    tables = []
    mask = mine(lut)
    for b in (np.unique(lut["branch"][mask]) if mask.any() else ()):
        rows = mask & (lut["branch"] == b)
        f, c = lut["thrust_n"][rows], lut["command"][rows]
        order_f = np.argsort(f)
        direction = str(lut["direction"][rows][0])
        tables.append((direction, f[order_f], c[order_f]))
    coefficients = {name: _coefficient_value(name, c)
                    for name, c in (doc.get("coefficients") or {}).items()}
    return _Depth(depth, volts, coefficients, cmd[ok], fit[ok], tables,
                  dict(doc.get("thrust_law") or {}))


def _coefficient_value(name: str, c: dict) -> Value:
    """A calibration.json coefficient as a Value."""
    return Value(name, _float(c.get("value")), _float(c.get("lo")), _float(c.get("hi")),
                 c.get("unit", ""), int(c.get("n") or 0), _float(c.get("r2")))


def _value(coef: dict[str, Value], name: str) -> float:
    c = coef.get(name)
    return math.nan if c is None else c.value


def _number(v: object) -> float:
    """A JSON number as a float, NaN for anything else (null, text)."""
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else math.nan


def _consumer(name: str, c: dict) -> ConsumerModel:
    """calibration.json's account of one simpler model, read defensively."""
    params = {k: _coefficient_value(k, v) for k, v in c.items()
              if isinstance(v, dict) and isinstance(v.get("value"), (int, float))}
    return ConsumerModel(name, str(c.get("equation", "")), params, _number(c.get("error_n")),
                         _number(c.get("error_frac")), c.get("adequate") is True)


def _float(v: object) -> float:
    return math.nan if v is None else float(v)  # type: ignore[arg-type]


def _like(template: Any, values: np.ndarray) -> Any:
    """A Python float for a scalar input, the array otherwise."""
    return float(values) if np.ndim(template) == 0 else values


TEXT_COLUMNS = ("state", "direction")


def _columns(names: list[str], rows: Iterable[list[object]]) -> Columns:
    data = list(rows)
    out = Columns()
    for i, name in enumerate(names):
        values = [r[i] for r in data]
        out[name] = (np.array(values, dtype=str) if name in TEXT_COLUMNS
                     else np.array(values, dtype=float))
    return out


def _read_csv(path: Path, needs: tuple[str, ...]) -> Columns:
    """A size-capped UTF-8 calibration CSV (comments, header, rows; `nan` missing) as columns."""
    if not path.is_file():
        raise UsageError(f"{path} is missing: the calibration folder is incomplete")
    text = decode_utf8(path, read_regular_bytes(path, MAX_CSV_BYTES))
    numbered = [(i, ln) for i, ln in enumerate(text.splitlines(), 1) if ln and ln[0] != "#"]
    if not numbered:
        raise UsageError(f"{path}: no header row")
    if len(numbered) > MAX_CSV_ROWS + 1:
        raise UsageError(f"{path}: {len(numbered) - 1:,} rows; the limit is {MAX_CSV_ROWS:,}")
    names = _header(path, numbered[0], needs)
    rows = []
    for number, line in numbered[1:]:
        cells = line.split(",", len(names))
        if len(cells) != len(names):
            raise UsageError(f"{path}:{number}: {line.count(',') + 1} cells, the header has "
                             f"{len(names)}")
        rows.append([c if n in TEXT_COLUMNS else _cell(path, number, n, c)
                     for n, c in zip(names, cells, strict=True)])
    return _columns(names, rows)


def _cell(path: Path, number: int, name: str, cell: str) -> float:
    """A numeric CSV cell; UsageError names the file, line and column of a bad one."""
    try:
        return float(cell)
    except ValueError:
        raise UsageError(f"{path}:{number}: could not convert {show(cell)} to a number "
                         f"(column {show(name)})") from None


def _header(path: Path, line: tuple[int, str], needs: tuple[str, ...]) -> list[str]:
    """The column names of a calibration CSV's header line, each once, `needs` among them."""
    number, text = line
    names = text.split(",", MAX_CSV_COLUMNS)
    if len(names) > MAX_CSV_COLUMNS:
        raise UsageError(f"{path}:{number}: more than {MAX_CSV_COLUMNS} columns")
    missing = [n for n in needs if n not in names]
    if missing:
        raise UsageError(f"{path}:{number}: no column {missing[0]!r} in the header")
    repeated = [n for n, count in Counter(names).items() if count > 1]
    if repeated:
        raise UsageError(f"{path}:{number}: column {show(repeated[0])} appears twice")
    return names


def vehicle_thrusters(vehicle: Vehicle, folders: dict[str, Path]) -> dict[str, ThrusterInput]:
    """Each thruster's calibration as identification takes it: thrust of a command at the
    thruster's `depth_m` (deepest when unset) and its lag (`lag_s`, else the calibration's
    step-response time constant, else none)."""
    loaded: dict[Path, Calibration] = {}
    out = {}
    for t in vehicle.thrusters:
        folder = folders[t.name]
        cal = loaded.setdefault(folder, load_calibration(folder))
        lag = t.lag_s
        if lag is None:
            tc = cal.dynamics.time_constant_s if cal.dynamics is not None else math.nan
            lag = tc if math.isfinite(tc) and tc > 0 else 0.0

        def thrust(command: np.ndarray, cal: Calibration = cal, depth: float | None = t.depth_m
                   ) -> np.ndarray:
            return np.asarray(cal.thrust(command, depth), dtype=float)

        out[t.name] = ThrusterInput(thrust, float(lag), str(folder))
    return out


def identify_vehicle(vehicle_file: str | os.PathLike[str], logs: Sequence[str | os.PathLike[str]],
                     out_dir: str | os.PathLike[str] = "vehicle-model", *, method: str = "nls",
                     dofs: str | None = None, seed: int = 1, link: str = "base_link",
                     namespace: str | None = None,
                     progress: ProgressHook = no_progress) -> Identification:
    """Identify the vehicle of `vehicle_file` from free-running `logs` (docs/vehicle.md) and
    write vehicle_model.json, identification.json, identification.html and the gz-sim and
    uuv_simulator blocks (for the model link `link`) to `out_dir`; `progress(task, done,
    total)` hears of the long fits."""
    if method not in METHODS:
        raise UsageError(f"method {method!r}: choose from {', '.join(METHODS)}")
    vehicle, folders = load_vehicle(vehicle_file)
    ident, _ = vehicle_workflow.identify_vehicle(
        vehicle, [Path(p) for p in logs], vehicle_thrusters(vehicle, folders), Path(out_dir),
        method, vehicle_workflow.parse_dofs(dofs), seed, HydroOptions(link, namespace),
        progress)
    return ident
