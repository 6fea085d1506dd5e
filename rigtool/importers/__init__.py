"""`rigtool import`: bring existing thrust-stand logs (Tyto/RCbenchmark or any CSV) and
manufacturers' workbooks (.xlsx, one sheet per supply voltage) into the store."""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rigtool.errors import UsageError
from rigtool.files import MAX_TABLE_BYTES, read_regular_bytes
from rigtool.importers import workbook
from rigtool.importers.generic import Parsed, parse_chunks
from rigtool.importers.mapping import Mapping, load_mapping, with_overrides
from rigtool.importers.steps import (
    TEMPERATURE_CHANNEL,
    ImportedPoints,
    choose_format,
    point_steps,
    ramp_keys,
    timeseries_steps,
)
from rigtool.importers.table import read_table_chunks, scan
from rigtool.importers.writer import protocol_for, write_run
from rigtool.store import Store

__all__ = ["ImportResult", "Mapping", "RowErrors", "import_file", "load_mapping", "with_overrides"]
MAX_STORED_ERRORS = 200
MAX_LISTED_ERRORS = 200  # unreadable cells listed in a --strict error
TEMPERATURE_EVENT_POINTS = 10_000  # points per `temperature` event (one JSON field < 16 MiB)
# the thrust axis an imported torque column is about: torque `tx` about thrust on `fx`
IMPORT_THRUST_AXIS = {"channel": "fx", "sign": 1}


class RowErrors(UsageError):
    """Some rows could not be read and --strict was given; the message lists them by line."""


@dataclass
class ImportResult:
    """What one imported file became: the run, and how many rows were read or skipped."""

    path: Path
    run_id: str | None
    importer: str
    fmt: str
    command_unit: str
    n_rows: int
    n_skipped: int
    n_steps: int
    errors: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # workbook sheets skipped as not data

    @property
    def n_read(self) -> int:
        return self.n_rows - self.n_skipped

    def headline(self) -> str:
        """One line: file, run id, rows read/skipped, points."""
        return (f"{self.path}: {self.n_read} row(s) read, {self.n_skipped} skipped -> "
                f"{self.n_steps} point(s) ({self.importer}, {self.fmt}, {self.command_unit}), "
                f"run {self.run_id}")

    def summary(self) -> str:
        """The headline, then one `note:` line per workbook sheet skipped."""
        return "\n".join([self.headline(), *(f"  note: {n}" for n in self.notes)])


@dataclass
class _Source:
    """What one file parsed into: the table, its digest, and a workbook's sheets and notes."""

    parsed: Parsed
    sha256: str
    sheets: list[dict] | None = None
    notes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


def _read(path: Path, m: Mapping) -> _Source:
    """Parse a text table, chunk by chunk, or an .xlsx workbook (by its name, or a ZIP archive
    under any name), which is read whole."""
    if workbook.is_workbook(path):
        book = workbook.read_workbook(path, m)
        return _Source(book.parsed, book.sha256, book.sheets, book.notes, book.warnings)
    head, encoding = scan(path)
    if workbook.is_workbook(path, head):
        book = workbook.read_workbook(path, m, read_regular_bytes(path, MAX_TABLE_BYTES))
        return _Source(book.parsed, book.sha256, book.sheets, book.notes, book.warnings)
    digest = hashlib.sha256()
    chunks = read_table_chunks(path, encoding=encoding, digest=digest, delimiter=m.delimiter,
                               decimal=m.decimal, header_row=m.header_row)
    parsed = parse_chunks(chunks, m)
    return _Source(parsed, digest.hexdigest())


def _drop_unmeasured_torque(source: _Source) -> None:
    """A torque column holding nothing but 0 (a stand without a torque cell logs one) is not
    a measurement: dropped with a warning, so no C_q of zero is fitted from it."""
    parsed = source.parsed
    torque = parsed.values.get("torque")
    if torque is None or np.any(np.nan_to_num(torque)):
        return
    header = parsed.columns.pop("torque").header
    del parsed.values["torque"]
    warning = f"torque column {header!r} holds only zeros or empty cells: not measured, ignored"
    (source.warnings if source.sheets is not None else parsed.warnings).append(warning)


def _rig(path: Path, source: _Source, mapping: Mapping, fmt: str) -> dict:
    parsed = source.parsed
    resolved: dict = {"kind": "import"}
    torque = parsed.values.get("torque")
    if torque is not None and np.isfinite(torque).any():
        resolved["thrust"] = dict(IMPORT_THRUST_AXIS)
    doc = {
        "name": f"import:{parsed.importer}",
        "description": f"imported from {path.name}",
        "resolved": resolved,
        "import": {
            "files": [{"name": path.name, "path": str(path), "sha256": source.sha256}],
            "importer": parsed.importer, "format": fmt,
            "columns": {f: {"header": c.header, "unit": c.unit, "factor_to_si": c.factor,
                            **({"offset_to_si": c.offset} if c.offset else {})}
                        for f, c in parsed.columns.items()},
            "command_unit": parsed.command_unit,
            "mapping": mapping.model_dump(),
        },
    }
    if mapping.sensor_accuracy is not None:
        doc["import"]["sensor_accuracy"] = mapping.sensor_accuracy.model_dump()
    if source.sheets is not None:
        doc["import"]["sheets"] = source.sheets
        doc["import"]["skipped_sheets"] = source.notes
    return doc


def temperature_events(points: ImportedPoints, parsed: Parsed) -> list[tuple[str, dict]]:
    """The temperature column kept per point: `temperature` events of up to
    TEMPERATURE_EVENT_POINTS points each (step idx, mean, min and max in °C). The store has no
    sample column for it, so it lives in events (Run.events("temperature") in the API)."""
    t = points.samples.get(TEMPERATURE_CHANNEL)
    if t is None or not len(points) or not np.isfinite(t).any():
        return []
    starts = points.bounds[:-1]
    ok = np.isfinite(t)
    count = np.add.reduceat(ok.astype(float), starts)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.add.reduceat(np.where(ok, t, 0.0), starts) / count
    low = np.minimum.reduceat(np.where(ok, t, np.inf), starts)
    high = np.maximum.reduceat(np.where(ok, t, -np.inf), starts)
    idx = np.flatnonzero(count > 0)
    header = parsed.columns["temperature"].header[:200]
    events = []
    for a in range(0, idx.size, TEMPERATURE_EVENT_POINTS):
        pick = idx[a:a + TEMPERATURE_EVENT_POINTS]
        events.append(("temperature", {
            "message": f"temperature of points {int(pick[0])}..{int(pick[-1])} from column "
                       f"{header!r} (°C: mean, min, max per point)",
            "column": header, "unit": "°C", "step_idx": pick.tolist(),
            "mean_c": np.round(mean[pick], 4).tolist(), "min_c": np.round(low[pick], 4).tolist(),
            "max_c": np.round(high[pick], 4).tolist()}))
    return events


RAMP_NOTE = ("read as a command ramp, binned by command and taken as steady: on a ramp the "
             "propeller's speed lags the command, so its thrust reads low going up and high "
             "going down; sweep up and down (the mean of the two is steadier) or ramp slower "
             "to check")


def _points(path: Path, parsed: Parsed, fmt: str, m: Mapping,
            depth_m: float | None) -> tuple[ImportedPoints, list[str]]:
    """The points of a table in format `fmt`: a time series (or step log: every sample kept,
    each command's first row its step time) grouped by command, or one point per row."""
    if fmt in ("timeseries", "steps", "ramp") and "time" not in parsed.values:
        raise UsageError(f"{path}: format {fmt} needs a time column (--col time=COLUMN)")
    if fmt == "steps" and m.settle_s > 0:
        raise UsageError(f"{path}: a step log keeps every sample from each step on: drop "
                         f"--settle-s {m.settle_s:g} (format steps)")
    if fmt in ("timeseries", "steps"):
        return timeseries_steps(parsed, m.settle_s, depth_m)
    if fmt == "ramp":
        points, notes = timeseries_steps(parsed, 0.0, depth_m, ramp_keys(parsed, depth_m))
        return points, [*notes, RAMP_NOTE]
    return point_steps(parsed, depth_m)


def import_file(store: Store, path: str | Path, mapping: Mapping | None = None, *,
                name: str | None = None, thruster_id: str | None = None,
                depth_m: float | None = None, strict: bool = False) -> ImportResult:
    """Read one log file and store it as a completed run (unless --strict and rows are bad)."""
    path = Path(path)
    m = mapping or Mapping()
    if depth_m is not None and not math.isfinite(depth_m):
        raise UsageError(f"--depth {depth_m!r}: must be a finite number of metres")
    source = _read(path, m)
    _drop_unmeasured_torque(source)
    parsed = source.parsed
    if strict and parsed.errors:
        more = len(parsed.errors) - MAX_LISTED_ERRORS
        raise RowErrors(f"{path}: {len(parsed.errors)} unreadable cell(s), nothing imported "
                        "(--strict):\n" + "\n".join(parsed.errors[:MAX_LISTED_ERRORS])
                        + (f"\n... and {more} more" if more > 0 else ""))
    if parsed.lines.size == 0:
        raise UsageError(f"{path}: no readable data rows"
                         + (":\n" + "\n".join(parsed.errors[:20]) if parsed.errors else ""))
    fmt = choose_format(parsed, m.format, depth_m)
    points, notes = _points(path, parsed, fmt, m, depth_m)
    if not len(points):
        raise UsageError(f"{path}: no points left after the settling cut: lower --settle-s")
    warnings = source.warnings if source.sheets is not None else parsed.warnings
    warnings = warnings + notes
    result = ImportResult(path, None, parsed.importer, fmt, parsed.command_unit, parsed.n_rows,
                          parsed.n_skipped, len(points), parsed.errors, warnings, source.notes)
    metadata = {"thruster_id": thruster_id, "source_file": path.name}
    run_name = name or path.stem
    protocol = protocol_for(run_name, parsed.command_unit, m.neutral, points, metadata, path.name,
                            steps=fmt == "steps")
    events = [("import", {"message": result.headline().replace(", run None", ""),
                          "rows": parsed.n_rows, "skipped": parsed.n_skipped,
                          "errors": parsed.errors[:MAX_STORED_ERRORS],
                          **({"notes": source.notes} if source.notes else {})})]
    if parsed.errors:
        events.append(("warning", {"message": f"{parsed.n_skipped} row(s) of {path.name} "
                                              f"skipped as unreadable, first: {parsed.errors[0]}"}))
    events += [("warning", {"message": w}) for w in warnings]
    events += temperature_events(points, parsed)
    result.run_id = write_run(store, name=run_name, protocol=protocol,
                              rig=_rig(path, source, m, fmt), points=points, events=events)
    return result
