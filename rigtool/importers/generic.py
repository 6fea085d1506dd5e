"""Turn a raw table into typed SI columns with a mapping; unreadable rows are reported by line."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from rigtool.errors import UsageError
from rigtool.importers import rcbenchmark, units
from rigtool.importers.mapping import Mapping
from rigtool.importers.table import RawTable

REQUIRED = ("command", "thrust")


@dataclass
class ColumnRef:
    """One mapped column: its position, header cell and factor to the stored SI unit."""

    field: str
    index: int
    header: str
    unit: str | None
    factor: float


@dataclass
class Parsed:
    """The good rows of a table as SI arrays (NaN where an optional cell is empty)."""

    importer: str
    columns: dict[str, ColumnRef]
    command_unit: str
    values: dict[str, np.ndarray]
    lines: np.ndarray
    n_rows: int
    errors: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    @property
    def n_skipped(self) -> int:
        return self.n_rows - int(self.lines.size)


def parse_number(text: str, decimal: str) -> float | None:
    """A finite float from a cell (None if empty); ValueError with the reason otherwise."""
    s = text.strip()
    if not s:
        return None
    if decimal == ",":
        s = s.replace(",", ".")
    elif "," in s:
        raise ValueError(f"{text.strip()!r} is not a number (comma decimal? use --decimal-comma)")
    try:
        x = float(s)
    except ValueError:
        raise ValueError(f"{text.strip()!r} is not a number") from None
    if not math.isfinite(x):
        raise ValueError(f"{text.strip()!r} is not a finite number")
    return x


def _find(header: list[str], ref: str | int, fld: str, path: str) -> int:
    if isinstance(ref, int):
        if not 1 <= ref <= len(header):
            raise UsageError(f"{path}: {fld}: column {ref} out of range 1..{len(header)}")
        return ref - 1
    want = ref.strip().lower()
    for i, h in enumerate(header):
        if h.lower() == want:
            return i
    for i, h in enumerate(header):
        if units.split_header(h)[0].lower() == want:
            return i
    raise UsageError(f"{path}: {fld}: no column {ref!r}; columns are: "
                     + ", ".join(repr(h) for h in header))


def resolve_columns(table: RawTable, mapping: Mapping) -> tuple[str, dict[str, ColumnRef], str,
                                                                  list[str]]:
    """Choose importer and columns: Tyto/RCbenchmark headers are recognised, the mapping wins."""
    path = str(table.path)
    given = {k: v for k, v in mapping.columns.model_dump().items() if v is not None}
    guessed = rcbenchmark.guess_columns(table.header) if rcbenchmark.detect(table.header) else {}
    importer = "rcbenchmark" if guessed else "generic"
    chosen = {**guessed, **given}
    missing = [f for f in REQUIRED if f not in chosen]
    if missing:
        raise UsageError(
            f"{path}: not a recognised thrust-stand log and no column given for "
            f"{', '.join(missing)}: use --col {missing[0]}=COLUMN or --mapping FILE; columns are: "
            + ", ".join(repr(h) for h in table.header))
    warnings: list[str] = []
    refs: dict[str, ColumnRef] = {}
    explicit_units = mapping.units.model_dump()
    for fld, ref in chosen.items():
        idx = _find(table.header, ref, fld, path)
        header = table.header[idx]
        unit = explicit_units.get(fld) or units.split_header(header)[1]
        if fld in ("command", "n_samples"):
            refs[fld] = ColumnRef(fld, idx, header, unit, 1.0)
            continue
        scale = units.factor(fld, unit)
        if fld == "speed" and (units.normalise(unit or "") == "erpm"
                               or rcbenchmark.is_electrical(header)):
            if mapping.pole_pairs is None:
                warnings.append(f"speed column {header!r} is electrical speed: ignored "
                                "(give --pole-pairs to convert it to propeller speed)")
                continue
            scale /= mapping.pole_pairs
        if fld == "thrust":
            scale *= mapping.thrust_sign
        refs[fld] = ColumnRef(fld, idx, header, unit, scale)
    command_unit = mapping.command_unit or units.command_unit(refs["command"].unit)
    if command_unit is None:
        raise UsageError(f"{path}: unknown command unit for column {refs['command'].header!r}: "
                         "give --command-unit (pulse_us, percent, pwm_counts, rpm, amps)")
    return importer, refs, command_unit, warnings


def parse(table: RawTable, mapping: Mapping) -> Parsed:
    """Read every data row; a row with an unreadable mapped cell is skipped and reported."""
    importer, refs, command_unit, warnings = resolve_columns(table, mapping)
    out: dict[str, list[float]] = {f: [] for f in refs}
    lines: list[int] = []
    errors: list[str] = []
    for line, cells in table.rows:
        row: dict[str, float] = {}
        problems = []
        for fld, ref in refs.items():
            cell = cells[ref.index] if ref.index < len(cells) else ""
            try:
                value = parse_number(cell, mapping.decimal)
            except ValueError as exc:
                problems.append(f"{fld}: {exc}")
                continue
            if value is None:
                if fld in REQUIRED:
                    problems.append(f"{fld}: empty" if ref.index < len(cells)
                                    else f"{fld}: missing (row has {len(cells)} cells)")
                value = math.nan
            row[fld] = value * ref.factor
        if problems:
            errors += [f"{table.path}:{line}: {p}" for p in problems]
            continue
        for fld, value in row.items():
            out[fld].append(value)
        lines.append(line)
    values = {f: np.asarray(v, dtype=float) for f, v in out.items()}
    return Parsed(importer, refs, command_unit, values, np.asarray(lines, dtype=int),
                  len(table.rows), errors, warnings)

