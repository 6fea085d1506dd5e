"""Turn a raw table into typed SI columns with a mapping; unreadable rows are reported by line."""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator
from dataclasses import dataclass, field, replace

import numpy as np

from rigtool.bounds import MAX_COMMAND
from rigtool.errors import UsageError
from rigtool.importers import rcbenchmark, units
from rigtool.importers.mapping import Mapping
from rigtool.importers.table import RawTable
from rigtool.units import NEUTRAL_BY_UNIT

REQUIRED = ("command", "thrust")
MAX_SHOWN_CELL = 40  # characters of a bad cell quoted in its error message
MAX_SUPPLY_LEVELS = 20  # a voltage column with at most this many levels may hold set voltages
MIN_LEVEL_ROWS = 5  # ... each level a sweep of at least this many commands
SPARE_SPEED = "electrical_speed"  # a log's eRPM column, read beside its optical speed
SPEED_RATIO_TOLERANCE = 0.15  # eRPM/optical this close to 1 (or to P): mechanical (electrical)
MIN_COMPARED_ROWS = 3  # rows with both speeds turning, to compare them
COMPARED_SPEED_FRAC = 0.1  # ... above this fraction of the top optical speed (noise below)


@dataclass
class ColumnRef:
    """One mapped column: its position, header cell, and factor (then offset) to the stored
    unit (SI; temperature in °C)."""

    field: str
    index: int
    header: str
    unit: str | None
    factor: float
    offset: float = 0.0


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


def shown(text: str) -> str:
    """A cell quoted for an error message, cut short if long (a hostile cell can be huge)."""
    s = text.strip()
    if len(s) <= MAX_SHOWN_CELL:
        return repr(s)
    return f"{s[:MAX_SHOWN_CELL - 8]!r}... ({len(s)} characters)"


def parse_number(text: str, decimal: str) -> float | None:
    """A finite float from a cell (None if empty); ValueError with the reason otherwise."""
    s = text.strip()
    if not s:
        return None
    if decimal == ",":
        s = s.replace(",", ".")
    elif "," in s:
        raise ValueError(f"{shown(text)} is not a number (comma decimal? use --decimal-comma)")
    try:
        x = float(s)
    except ValueError:
        raise ValueError(f"{shown(text)} is not a number") from None
    if not math.isfinite(x):
        raise ValueError(f"{shown(text)} is not a finite number")
    return x


def _find(header: list[str], ref: str | int, fld: str, path: str) -> int:
    if isinstance(ref, int):
        if not 1 <= ref <= len(header):
            raise UsageError(f"{path}: {fld}: column {ref} out of range 1..{len(header)}")
        return ref - 1
    want = ref.strip().lower()
    for matches in ([i for i, h in enumerate(header) if h.lower() == want],
                    [i for i, h in enumerate(header) if units.split_header(h)[0].lower() == want]):
        if len(matches) == 1:
            return matches[0]
        if matches:
            listed = ", ".join(f"{i + 1} ({header[i]!r})" for i in matches)
            raise UsageError(f"{path}: {fld}: column name {ref!r} is ambiguous, it matches "
                             f"columns {listed}: give the column number (--col {fld}="
                             f"{matches[0] + 1}) or a header that names one column")
    raise UsageError(f"{path}: {fld}: no column {shown(ref)}; columns are: "
                     + ", ".join(repr(h) for h in header))


def resolve_columns(table: RawTable, mapping: Mapping) -> tuple[str, dict[str, ColumnRef], str,
                                                                  list[str]]:
    """Choose importer and columns: Tyto/RCbenchmark headers are recognised, the mapping wins."""
    path = str(table.path)
    given = {k: v for k, v in mapping.columns.model_dump().items() if v is not None}
    if table.headerless:
        _refuse_names(table, given)
    detected = rcbenchmark.detect(table.header)
    chosen = {**_recognised(table, given, detected), **given}
    # the command and thrust mapped by hand: a generic table, whatever its other headers
    importer = "rcbenchmark" if detected and not all(f in given for f in REQUIRED) else "generic"
    missing = [f for f in REQUIRED if f not in chosen]
    if missing:
        raise UsageError(
            f"{path}: not a recognised thrust-stand log and no column given for "
            f"{', '.join(missing)}: use --col {missing[0]}=COLUMN or --mapping FILE; columns are: "
            + ", ".join(repr(h) for h in table.header)
            + (" (no header line: give columns by number)" if table.headerless else ""))
    warnings: list[str] = []
    if table.headerless:
        warnings.append(f"no header line: line {table.header_line} holds only numbers and is "
                        "read as data")
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
        if fld == "speed" and _electrical(header, unit):
            if mapping.pole_pairs is None:
                warnings.append(f"speed column {header!r} is electrical speed: ignored "
                                "(give --pole-pairs to convert it to propeller speed)")
                continue
            scale /= mapping.pole_pairs
        if fld in ("thrust", "torque"):  # --flip-thrust turns the thrust axis, torque with it
            scale *= mapping.thrust_sign
        refs[fld] = ColumnRef(fld, idx, header, unit, scale, units.offset(fld, unit))
    spare = _spare_speed(table, refs) if detected and "speed" not in given else None
    if spare is not None:
        refs[SPARE_SPEED] = spare
    command_unit = mapping.command_unit or units.command_unit(refs["command"].unit)
    if command_unit is None:
        raise UsageError(f"{path}: unknown command unit for column {refs['command'].header!r}: "
                         f"give --command-unit ({', '.join(units.KNOWN_COMMAND_UNITS)})")
    return importer, refs, command_unit, warnings


def _refuse_names(table: RawTable, given: dict[str, str | int]) -> None:
    """UsageError for a column given by name in a file with no header line: its columns have
    no names, only numbers."""
    named = [f for f, ref in given.items() if isinstance(ref, str)]
    if named:
        raise UsageError(f"{table.path}: no header line (line {table.header_line} holds only "
                         f"numbers and is read as data), so its columns have no names: give "
                         f"{', '.join(named)} by column number, e.g. --col {named[0]}=2")


def _spare_speed(table: RawTable, refs: dict[str, ColumnRef]) -> ColumnRef | None:
    """The log's eRPM column as logged (not divided by pole pairs) beside a recognised speed
    column that is not electrical: read to replace an optical column that holds no reading,
    or to tell from both whether the eRPM column is electrical or already mechanical."""
    speed = refs.get("speed")
    header = rcbenchmark.electrical_speed_column(table.header)
    if speed is None or header is None or _electrical(speed.header, speed.unit):
        return None
    unit = units.split_header(header)[1]
    scale = units.FACTORS["speed"].get(units.normalise(unit) if unit else "rpm")
    if scale is None:
        return None
    return ColumnRef("speed", table.header.index(header), header, unit, scale)


def _electrical(header: str, unit: str | None) -> bool:
    """Whether a speed column is electrical speed (divided by the pole pairs to be used)."""
    return units.normalise(unit or "") == "erpm" or rcbenchmark.is_electrical(header)


def _recognised(table: RawTable, given: dict[str, str | int], detected: bool) -> dict[str, str]:
    """Columns recognised by their headers: every known one in a Tyto/RCbenchmark-style log;
    in any other table the supply voltage (`Supply Voltage (V)`) only, unless the mapping
    gives its column to another field."""
    found = rcbenchmark.guess_columns(table.header)
    if detected:
        return found
    taken = {_find(table.header, ref, fld, str(table.path)) for fld, ref in given.items()}
    return {f: h for f, h in found.items() if f in rcbenchmark.ALWAYS_RECOGNISED
            and table.header.index(h) not in taken}


def _column(cells: list[str], fld: str, ref: ColumnRef, widths: np.ndarray, decimal: str,
            problems: dict[int, list[str]]) -> np.ndarray:
    """One mapped column in SI (NaN where an optional cell is empty); bad cells go to `problems`.

    The whole column is converted at once; only a column holding a bad cell is read cell by
    cell, to say which rows are bad and why.
    """
    text = [c.replace(",", ".") for c in cells] if decimal == "," else cells
    try:
        with np.errstate(over="ignore", invalid="ignore"):
            values = np.asarray(text, dtype=float) * ref.factor + ref.offset
        if np.all(np.isfinite(values)):
            return values
    except ValueError:
        pass
    values = np.full(len(cells), np.nan)
    for i, cell in enumerate(cells):
        try:
            value = parse_number(cell, decimal)
        except ValueError as exc:
            problems.setdefault(i, []).append(f"{fld}: {exc}")
            continue
        if value is None:
            if fld in REQUIRED:
                problems.setdefault(i, []).append(
                    f"{fld}: empty" if ref.index < widths[i]
                    else f"{fld}: missing (row has {widths[i]} cells)")
        elif not math.isfinite(value * ref.factor + ref.offset):
            problems.setdefault(i, []).append(
                f"{fld}: {shown(cell)} is too large once converted from "
                f"{ref.unit or 'its unit'} (x {ref.factor:g})")
        else:
            values[i] = value * ref.factor + ref.offset
    return values


def _overlong_rows(table: RawTable, decimal: str) -> dict[int, list[str]]:
    """Rows with a number beyond the header's columns: two rows run together, or cells
    shifted, so no cell of the row can be trusted to be in its column. Empty trailing cells
    (a trailing separator) and a text note after the last column are fine, and so is anything
    right of a workbook's table (its cells have fixed places: no delimiter to lose)."""
    width = len(table.header)
    if not table.delimiter:
        return {}
    return {i: [f"row has {len(cells):,} cells, the header {width}, with numbers beyond it: "
                "cells shifted or two rows on one line"]
            for i, (_, cells) in enumerate(table.rows)
            if len(cells) > width and any(_is_number(c, decimal) for c in cells[width:])}


def _is_number(cell: str, decimal: str) -> bool:
    """Whether a cell reads as a number, as the file's mapped cells are read."""
    try:
        return parse_number(cell, decimal) is not None
    except ValueError:
        return False


def parse(table: RawTable, mapping: Mapping) -> Parsed:
    """Read every data row; a row with an unreadable mapped cell is skipped and reported."""
    return parse_chunks(iter([table]), mapping)


def parse_chunks(tables: Iterator[RawTable], mapping: Mapping) -> Parsed:
    """`parse` of a table read in chunks (`read_table_chunks`): each chunk's cells become SI
    columns before the next is read, so only the numbers of the whole file are held."""
    first = next(tables)
    first_overlong = _overlong_rows(first, mapping.decimal)
    # Most rows of the first chunk with numbers beyond the header: a logger that writes a
    # column without a name, not rows run together (its cells are ignored).
    unnamed = 2 * len(first_overlong) > len(first.rows)
    importer, refs, command_unit, warnings = resolve_columns(first, mapping)
    problems: dict[int, list[str]] = {}
    spare_problems: dict[int, list[str]] = {}  # the eRPM column's: only if it is used
    parts: dict[str, list[np.ndarray]] = {fld: [] for fld in refs}
    row_lines: list[np.ndarray] = []
    bad: list[tuple[int, str]] = []
    n = 0
    for table in itertools.chain([first], tables):
        widths = np.fromiter((len(cells) for _, cells in table.rows), dtype=np.int64,
                             count=len(table.rows))
        if unnamed:
            local = {}
        else:
            local = first_overlong if table is first else _overlong_rows(table, mapping.decimal)
        spare_local: dict[int, list[str]] = {}
        for fld, ref in refs.items():
            j = ref.index
            cells = [cells[j] if j < len(cells) else "" for _, cells in table.rows]
            parts[fld].append(_column(cells, ref.field, ref, widths, mapping.decimal,
                                      spare_local if fld == SPARE_SPEED else local))
        problems.update((n + i, ps) for i, ps in local.items())
        spare_problems.update((n + i, ps) for i, ps in spare_local.items())
        row_lines.append(np.fromiter((line for line, _ in table.rows), dtype=np.int64,
                                     count=len(table.rows)))
        bad += table.bad
        n += len(table.rows)
    columns = {fld: np.concatenate(p) for fld, p in parts.items()}
    del parts
    warnings += _choose_speed(columns, refs, problems, spare_problems, mapping.pole_pairs)
    if "thrust_std" in columns:
        with np.errstate(over="ignore", invalid="ignore"):
            spread = np.abs(columns["thrust"]) + np.abs(columns["thrust_std"])
        for i in np.flatnonzero(np.isinf(spread)).tolist():
            problems.setdefault(i, []).append(
                "thrust_std: thrust plus its standard deviation is too large")
    if "command" in columns:
        for i in np.flatnonzero(np.abs(columns["command"]) > MAX_COMMAND).tolist():
            problems.setdefault(i, []).append(
                f"command: {columns['command'][i]:g} is outside the commands rigtool stores "
                f"(|command| <= {MAX_COMMAND:g})")
    good = np.ones(n, dtype=bool)
    good[list(problems)] = False
    all_lines = np.concatenate(row_lines)
    errors = [(int(all_lines[i]), p) for i, ps in problems.items() for p in ps] + bad
    errors.sort(key=lambda e: e[0])
    values = {f: v[good] for f, v in columns.items()}
    del columns
    _refuse_pooled_supplies(values, refs, str(first.path))
    if mapping.neutral is None:
        _refuse_outside_neutral(values["command"], command_unit, str(first.path))
    return Parsed(importer, refs, command_unit, values, all_lines[good], n + len(bad),
                  [f"{first.path}:{line}: {p}" for line, p in errors], warnings)


def _unmeasured(values: np.ndarray) -> bool:
    """A column of nothing but 0 or empty cells: a sensor the stand does not have."""
    return not np.any(np.nan_to_num(values))


def _choose_speed(columns: dict[str, np.ndarray], refs: dict[str, ColumnRef],
                  problems: dict[int, list[str]], spare_problems: dict[int, list[str]],
                  pole_pairs: int | None) -> list[str]:
    """Settle the speed column from the log's own values; the warnings.

    A speed column of nothing but 0 or empty cells is ignored (else it would be preferred
    and no C_p fitted), the eRPM column divided by --pole-pairs taking its place. The eRPM
    column of a stand given the pole count is mechanical r/min already: read beside an
    optical column, their ratio tells (1: mechanical, P: electrical); read alone, a warning
    says how to check it.
    """
    spare = refs.pop(SPARE_SPEED, None)
    spare_values = columns.pop(SPARE_SPEED, np.zeros(0))
    speed = refs.get("speed")
    if speed is None:
        return []
    if not _unmeasured(columns["speed"]):
        if spare is not None and pole_pairs is not None:
            return _compare_speeds(speed, columns["speed"], spare, spare_values, pole_pairs)
        divided = pole_pairs is not None and _electrical(speed.header, speed.unit)
        return [_electrical_caveat(speed, pole_pairs)] if divided else []
    del refs["speed"], columns["speed"]
    ignored = (f"speed column {speed.header!r} holds only zeros or empty cells: not measured, "
               "ignored")
    if spare is None:
        return [f"{ignored}; no usable speed column"]
    if pole_pairs is None or _unmeasured(spare_values):
        why = ("is electrical speed: give --pole-pairs to use it" if pole_pairs is None
               else "holds none either")
        return [f"{ignored}; {spare.header!r} {why}; no usable speed column"]
    refs["speed"] = replace(spare, factor=spare.factor / pole_pairs)
    columns["speed"] = spare_values / pole_pairs
    for i, ps in spare_problems.items():
        problems.setdefault(i, []).extend(ps)
    return [f"{ignored}; speed from {spare.header!r} divided by --pole-pairs {pole_pairs}",
            _electrical_caveat(spare, pole_pairs)]


def _electrical_caveat(speed: ColumnRef, pole_pairs: int) -> str:
    """How an eRPM column divided by the pole pairs may be wrong, and how to tell."""
    return (f"speed column {speed.header!r} divided by --pole-pairs {pole_pairs} as electrical "
            "speed: a stand that was given the motor's pole count logs mechanical r/min there "
            f"already, and the speed is then {pole_pairs} x too low (C_p {pole_pairs ** 2} x too "
            "large); check it against an optical tachometer, or the motor's KV x voltage (its "
            "top speed unloaded)")


def _compare_speeds(speed: ColumnRef, optical: np.ndarray, spare: ColumnRef,
                    electrical: np.ndarray, pole_pairs: int) -> list[str]:
    """A warning when the eRPM column read beside the optical one is not P x it: already
    mechanical (ratio about 1), or neither (the pole pairs wrong)."""
    a, b = np.abs(optical), np.abs(electrical)
    with np.errstate(invalid="ignore"):
        ok = (a > COMPARED_SPEED_FRAC * np.nanmax(a)) & (b > 0)
    if np.count_nonzero(ok) < MIN_COMPARED_ROWS:
        return []
    ratio = float(np.median(b[ok] / a[ok]))
    if abs(ratio / pole_pairs - 1) <= SPEED_RATIO_TOLERANCE:
        return []
    if abs(ratio - 1) <= SPEED_RATIO_TOLERANCE:
        what = ("it is mechanical r/min already (the stand was given the pole count): "
                f"--pole-pairs {pole_pairs} does not apply to it")
    else:
        what = f"neither 1 (mechanical) nor --pole-pairs {pole_pairs}: check the pole pairs"
    return [f"speed column {spare.header!r} reads {ratio:.2f} x {speed.header!r}: {what}; "
            f"speed from {speed.header!r}"]


def _refuse_outside_neutral(command: np.ndarray, command_unit: str, path: str) -> None:
    """UsageError asking for --neutral when an analog throttle's default neutral of 0 V lies
    outside the logged commands (a 0.5-4.5 V throttle stops at 2.5 V): the stop would be
    taken beyond full reverse. In the other units the default stop (1500 us, 0 %, 0 counts)
    is the usual one, which a forward-only log lies beside."""
    default = NEUTRAL_BY_UNIT.get(command_unit, 0.0)
    finite = command[np.isfinite(command)]
    if (command_unit != "volts" or not finite.size
            or finite.min() <= default <= finite.max()):
        return
    raise UsageError(f"{path}: the commands run {finite.min():g}..{finite.max():g} "
                     f"({command_unit}), and the default neutral {default:g} is outside them: "
                     "give --neutral, the command at which the thruster stops (e.g. --neutral "
                     "2.5 for a 0.5-4.5 V throttle centred on 2.5 V)")


def supply_levels(values: dict[str, np.ndarray]) -> np.ndarray | None:
    """The levels of a `voltage` column that holds a few set voltages, each with its own sweep
    of the same commands (a maker's table of several voltages in one file, read without its
    supply column); None for anything else."""
    if "supply" in values or "voltage" not in values:
        return None
    v, cmd = values["voltage"], values["command"]
    ok = np.isfinite(v)
    levels, counts = np.unique(v[ok], return_counts=True)
    if not 2 <= levels.size <= MAX_SUPPLY_LEVELS or counts.min() < MIN_LEVEL_ROWS:
        return None
    sweeps = [np.unique(cmd[ok & (v == level)]) for level in levels]
    distinct = all(s.size == c for s, c in zip(sweeps, counts, strict=True))
    shared = sweeps[0]
    for s in sweeps[1:]:
        shared = np.intersect1d(shared, s)
    return levels if distinct and shared.size >= MIN_LEVEL_ROWS else None


def _refuse_pooled_supplies(values: dict[str, np.ndarray], refs: dict[str, ColumnRef],
                            path: str) -> None:
    """UsageError naming the voltage column when it holds several supply voltages that would
    otherwise be pooled into one calibration."""
    levels = supply_levels(values)
    if levels is None:
        return
    header = refs["voltage"].header
    shown_levels = ", ".join(f"{x:g}" for x in levels)
    raise UsageError(
        f"{path}: column {header!r} holds {levels.size} voltages ({shown_levels} V), each with "
        "its own sweep of the commands: a table of several supply voltages. Map it as the "
        f"supply voltage too (--col supply={header!r}, or a `Supply Voltage (V)` column) so "
        "each voltage is calibrated on its own, or import one voltage per file")
