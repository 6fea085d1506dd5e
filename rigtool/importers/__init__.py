"""`rigtool import`: bring existing thrust-stand logs (Tyto/RCbenchmark or any CSV) into the store."""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field
from pathlib import Path

from rigtool.errors import UsageError
from rigtool.importers.generic import Parsed, parse
from rigtool.importers.mapping import Mapping, load_mapping, with_overrides
from rigtool.importers.steps import ImportedPoints, choose_format, point_steps, timeseries_steps
from rigtool.importers.table import read_table
from rigtool.importers.writer import protocol_for, write_run
from rigtool.store import Store

__all__ = ["ImportResult", "Mapping", "RowErrors", "import_file", "load_mapping", "with_overrides"]
MAX_STORED_ERRORS = 200
MAX_LISTED_ERRORS = 200  # unreadable cells listed in a --strict error


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

    @property
    def n_read(self) -> int:
        return self.n_rows - self.n_skipped

    def summary(self) -> str:
        """One line: file, run id, rows read/skipped, points."""
        return (f"{self.path}: {self.n_read} row(s) read, {self.n_skipped} skipped -> "
                f"{self.n_steps} point(s) ({self.importer}, {self.fmt}, {self.command_unit}), "
                f"run {self.run_id}")


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _rig(path: Path, parsed: Parsed, mapping: Mapping, fmt: str) -> dict:
    return {
        "name": f"import:{parsed.importer}",
        "description": f"imported from {path.name}",
        "resolved": {"kind": "import"},
        "import": {
            "files": [{"name": path.name, "path": str(path), "sha256": _sha256(path)}],
            "importer": parsed.importer, "format": fmt,
            "columns": {f: {"header": c.header, "unit": c.unit, "factor_to_si": c.factor}
                        for f, c in parsed.columns.items()},
            "command_unit": parsed.command_unit,
            "mapping": mapping.model_dump(),
        },
    }


def _points(path: Path, parsed: Parsed, fmt: str, m: Mapping,
            depth_m: float | None) -> tuple[ImportedPoints, list[str]]:
    """The points of a table in format `fmt`: a time series (or step log: every sample kept,
    each command's first row its step time) grouped by command, or one point per row."""
    if fmt in ("timeseries", "steps") and "time" not in parsed.values:
        raise UsageError(f"{path}: format {fmt} needs a time column (--col time=COLUMN)")
    if fmt == "steps" and m.settle_s > 0:
        raise UsageError(f"{path}: a step log keeps every sample from each step on: drop "
                         f"--settle-s {m.settle_s:g} (format steps)")
    if fmt in ("timeseries", "steps"):
        return timeseries_steps(parsed, m.settle_s, depth_m)
    return point_steps(parsed, depth_m)


def import_file(store: Store, path: str | Path, mapping: Mapping | None = None, *,
                name: str | None = None, thruster_id: str | None = None,
                depth_m: float | None = None, strict: bool = False) -> ImportResult:
    """Read one log file and store it as a completed run (unless --strict and rows are bad)."""
    path = Path(path)
    m = mapping or Mapping()
    if depth_m is not None and not math.isfinite(depth_m):
        raise UsageError(f"--depth {depth_m!r}: must be a finite number of metres")
    table = read_table(path, delimiter=m.delimiter, decimal=m.decimal, header_row=m.header_row)
    parsed = parse(table, m)
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
    warnings = parsed.warnings + notes
    result = ImportResult(path, None, parsed.importer, fmt, parsed.command_unit, parsed.n_rows,
                          parsed.n_skipped, len(points), parsed.errors, warnings)
    metadata = {"thruster_id": thruster_id, "source_file": path.name}
    run_name = name or path.stem
    protocol = protocol_for(run_name, parsed.command_unit, m.neutral, points, metadata, path.name,
                            steps=fmt == "steps")
    events = [("import", {"message": result.summary().replace(", run None", ""),
                          "rows": parsed.n_rows, "skipped": parsed.n_skipped,
                          "errors": parsed.errors[:MAX_STORED_ERRORS]})]
    if parsed.errors:
        events.append(("warning", {"message": f"{parsed.n_skipped} row(s) of {path.name} "
                                              f"skipped as unreadable, first: {parsed.errors[0]}"}))
    events += [("warning", {"message": w}) for w in warnings]
    result.run_id = write_run(store, name=run_name, protocol=protocol,
                              rig=_rig(path, parsed, m, fmt), points=points, events=events)
    return result
