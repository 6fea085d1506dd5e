"""Excel workbooks (.xlsx): one table per worksheet, each sheet's supply voltage from its name.

Made for the Blue Robotics T200 public performance workbook
(`T200-Public-Performance-Data-10-20V-September-2019.xlsx`): a `READ ME FIRST` sheet of test
notes, then one sheet per supply voltage named `10 V`, `12 V` ... `20 V`, each with the header
row `PWM (µs)`, `RPM`, `Current (A)`, `Voltage (V)`, `Power (W)`, `Force (Kg f)`,
`Efficiency (g/W)` (some copies put a space before each name) and one row per 4 µs from 1100
to 1900 µs. Any workbook laid out that way reads the same, with the mapping of a CSV import.

The file is hostile until checked: its size and the declared unpacked size of its ZIP members
are bounded before openpyxl opens it (read-only, cached cell values only, so no formula is
ever evaluated), and the sheets, rows and columns read are bounded while it is read.
"""

from __future__ import annotations

import hashlib
import io
import re
import warnings
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rigtool.errors import UsageError
from rigtool.files import read_regular_bytes
from rigtool.importers import rcbenchmark
from rigtool.importers.generic import ColumnRef, Parsed, parse
from rigtool.importers.mapping import Mapping
from rigtool.importers.table import RawTable
from rigtool.importers.units import split_header

SUFFIXES = (".xlsx", ".xlsm")
ZIP_MAGIC = b"PK\x03\x04"
INSTALL_HINT = "pip install 'rigtool[xlsx]'"
MAX_WORKBOOK_BYTES = 256 << 20  # the .xlsx file itself
MAX_UNPACKED_BYTES = 256 << 20  # declared unpacked size of all its ZIP members (~8 M cells)
MAX_MEMBERS = 10_000  # ZIP members (sheets, styles, drawings...)
MAX_SHEETS = 64
MAX_ROWS = 1_000_000  # rows holding a value, all sheets together
MAX_SCANNED_ROWS = 2_000_000  # rows walked, empty ones included, all sheets together
MAX_COLUMNS = 128  # columns read per row; cells further right are ignored
MAX_HEADER_SCAN = 20  # rows with a value searched for the header row
MAX_CELL_CHARS = 1000  # a text cell is cut here: it is only ever quoted in a message
MAX_HEADER_CHARS = 200
MAX_SHOWN_NAME = 40  # characters of a sheet name quoted in a message
MAX_LISTED_FORMULAS = 5
VOLTAGE_LIMIT_V = 1000.0
# `10 V`, `12V`, `14.8 V`, `T200 16 V`, `16 volts`; not the `20V` of a range `10-20V`
VOLTAGE_IN_NAME = re.compile(r"(?<![\w.,+-])(\d{1,4}(?:[.,]\d{1,3})?)\s*(?:v|volts?)(?![a-z0-9])",
                             re.IGNORECASE)
SUPPLY_FROM_NAME = "sheet name"


@dataclass
class Sheet:
    """One data sheet read into text cells, and the supply voltage its name gives."""

    name: str
    table: RawTable  # its path names the workbook and the sheet, for messages
    voltage_v: float | None
    blank_columns: list[int] = field(default_factory=list)  # used columns with an empty cell


@dataclass
class WorkbookParsed:
    """The data sheets of a workbook parsed and joined into one table, and what was skipped."""

    parsed: Parsed
    sha256: str
    sheets: list[dict]  # per data sheet: name, voltage, where it came from, rows, columns
    notes: list[str]  # sheets that are not data (notes, charts), skipped
    warnings: list[str]


def is_workbook(path: Path, raw: bytes | None = None) -> bool:
    """An .xlsx/.xlsm name, or (given the bytes) a ZIP archive under any name."""
    return path.suffix.lower() in SUFFIXES or (raw is not None and raw.startswith(ZIP_MAGIC))


def sheet_label(name: str) -> str:
    """A sheet name as quoted in messages: escaped (it is text from the file) and cut short."""
    if len(name) <= MAX_SHOWN_NAME:
        return repr(name)
    return f"{name[:MAX_SHOWN_NAME - 8]!r}... ({len(name)} characters)"


def voltage_from_name(name: str) -> float | None:
    """The one supply voltage a sheet name gives (`16 V` -> 16.0), None for none or several."""
    found = VOLTAGE_IN_NAME.findall(name)
    if len(found) != 1:
        return None
    value = float(found[0].replace(",", "."))
    return value if 0 < value <= VOLTAGE_LIMIT_V else None


def _openpyxl(path: Path) -> Any:
    """The openpyxl module, or a one-line usage error saying how to install it."""
    try:
        import openpyxl
    except ImportError:
        raise UsageError(f"{path}: reading .xlsx workbooks needs openpyxl: "
                         f"{INSTALL_HINT}") from None
    return openpyxl


def _check_archive(path: Path, raw: bytes) -> None:
    """Refuse what is not a ZIP archive, or one that unpacks to more than the bounds allow."""
    try:
        with zipfile.ZipFile(io.BytesIO(raw)) as archive:
            members = archive.infolist()
    except (zipfile.BadZipFile, zipfile.LargeZipFile, ValueError, OSError) as exc:
        looks = "a text file? name it .csv" if _is_text(raw) else "not a ZIP archive"
        raise UsageError(f"{path}: not an .xlsx workbook ({looks}): {exc}") from None
    if len(members) > MAX_MEMBERS:
        raise UsageError(f"{path}: {len(members):,} parts in the archive, more than the "
                         f"{MAX_MEMBERS:,} a workbook may have")
    unpacked = sum(m.file_size for m in members)
    if unpacked > MAX_UNPACKED_BYTES:
        raise UsageError(f"{path}: unpacks to {unpacked:,} bytes, more than the "
                         f"{MAX_UNPACKED_BYTES >> 20} MiB a workbook may")


def _is_text(raw: bytes) -> bool:
    head = raw[:4096]
    return bool(head) and b"\x00" not in head and all(b >= 9 for b in head[:64])


def _load(openpyxl: Any, path: Path, raw: bytes, data_only: bool) -> Any:
    """The workbook, read-only; any failure inside openpyxl is the file's: a usage error."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return openpyxl.load_workbook(io.BytesIO(raw), read_only=True, data_only=data_only)
    except Exception as exc:  # a hostile file: whatever openpyxl raises is the file's fault
        raise UsageError(f"{path}: not a readable .xlsx workbook ({_reason(exc)})") from None


def _reason(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    text = text if len(text) <= 120 else text[:117] + "..."
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _text(value: object) -> str:
    """A cell value as the text a CSV would hold: numbers exactly (repr), empty for None."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return "TRUE" if value else "FALSE"
    if isinstance(value, (int, float)):
        try:
            return repr(float(value))
        except OverflowError:
            return "<a number too large for a float>"
    text = str(value)
    return text if len(text) <= MAX_CELL_CHARS else text[:MAX_CELL_CHARS]


class _Budget:
    """Rows walked and rows holding a value, across all sheets of one workbook."""

    def __init__(self, path: Path) -> None:
        self.path, self.scanned, self.rows = path, 0, 0

    def rows_left(self) -> int:
        return MAX_SCANNED_ROWS - self.scanned

    def walk(self) -> None:
        self.scanned += 1
        if self.scanned > MAX_SCANNED_ROWS:
            raise UsageError(f"{self.path}: more than {MAX_SCANNED_ROWS:,} rows (empty ones "
                             "counted): not a table rigtool reads")

    def hold(self) -> None:
        self.rows += 1
        if self.rows > MAX_ROWS:
            raise UsageError(f"{self.path}: more than {MAX_ROWS:,} rows of data in all its sheets")


def _rows(ws: Any, path: Path, label: str, budget: _Budget) -> Iterator[tuple[int, tuple]]:
    """(row number, values) of each row holding a value, within the bounds; openpyxl failures
    while reading are the file's."""
    rows = ws.iter_rows(min_row=1, max_row=budget.rows_left() + 1, min_col=1,
                        max_col=MAX_COLUMNS, values_only=True)
    number = 0
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for number, values in enumerate(rows, start=1):
                budget.walk()
                if values.count(None) != len(values):
                    budget.hold()
                    yield number, values
    except UsageError:
        raise
    except Exception as exc:  # a hostile file: whatever openpyxl raises is the file's fault
        raise UsageError(f"{path}[{label}]: cannot be read after row {number} "
                         f"({_reason(exc)})") from None


def _header_fields(header: list[str], mapping: Mapping) -> dict[str, int]:
    """Field -> column index of the command and thrust a header row gives (by the mapping or
    by recognised names); fewer than both: not a data header."""
    given = {k: v for k, v in mapping.columns.model_dump().items() if v is not None}
    found = rcbenchmark.guess_columns(header)
    out = {}
    for fld in ("command", "thrust"):
        ref = given.get(fld, found.get(fld))
        idx = _index(header, ref)
        if idx is not None:
            out[fld] = idx
    return out


def _index(header: list[str], ref: str | int | None) -> int | None:
    """Column index a mapping reference names in `header` (None: not there)."""
    if ref is None:
        return None
    if isinstance(ref, int):
        return ref - 1 if 1 <= ref <= len(header) else None
    want = ref.strip().lower()
    for i, h in enumerate(header):
        if h.lower() == want or split_header(h)[0].lower() == want:
            return i
    return None


def _used_columns(header: list[str], mapping: Mapping) -> list[int]:
    """Indices of every column the import may read from this header."""
    given = {k: v for k, v in mapping.columns.model_dump().items() if v is not None}
    refs = {**rcbenchmark.guess_columns(header), **given}
    return sorted({i for r in refs.values() if (i := _index(header, r)) is not None})


def _read_sheet(ws: Any, name: str, path: Path, mapping: Mapping,
                budget: _Budget) -> Sheet | str:
    """The sheet as a table, or why it is not data (a note)."""
    label = sheet_label(name)
    header: list[str] | None = None
    header_line = 0
    rows: list[tuple[int, list[str]]] = []
    seen = 0
    blanks = False
    used: list[int] = []
    for number, values in _rows(ws, path, label, budget):
        cells = [_text(v) for v in values]
        while cells and not cells[-1]:
            cells.pop()
        if header is None:
            seen += 1
            wanted = mapping.header_row is None or number == mapping.header_row
            candidate = [c.strip()[:MAX_HEADER_CHARS] for c in cells]
            if wanted and len(_header_fields(candidate, mapping)) == 2:
                header, header_line = candidate, number
                used = _used_columns(header, mapping)
            elif (mapping.header_row is None and seen >= MAX_HEADER_SCAN) or (
                    mapping.header_row is not None and number >= mapping.header_row):
                break
            continue
        rows.append((number, cells))
        blanks = blanks or any(j >= len(cells) or not cells[j] for j in used)
    if header is None:
        where = (f"row {mapping.header_row}" if mapping.header_row is not None
                 else f"its first {MAX_HEADER_SCAN} rows")
        return (f"sheet {label}: no command and thrust columns in {where} (notes, or a "
                "header rigtool does not know: give --col command=... --col thrust=...)")
    table = RawTable(Path(f"{path}[{label}]"), header, header_line, rows, "")
    return Sheet(name, table, voltage_from_name(name), used if blanks else [])


def _formula_cells(wb: Any, sheet: Sheet, path: Path) -> list[str]:
    """Cells of the used columns that hold a formula with no stored result: openpyxl reads
    them as empty, so they are found in a second, formula-keeping read of the sheet."""
    from openpyxl.utils import get_column_letter

    used, texts = sheet.blank_columns, dict(sheet.table.rows)
    last = max(texts, default=0)
    out: list[str] = []
    budget = _Budget(path)
    for number, values in _rows(wb[sheet.name], path, sheet_label(sheet.name), budget):
        if number > last:
            break
        cells = texts.get(number)
        if cells is None:
            continue
        for j in used:
            stored = cells[j] if j < len(cells) else ""
            if not stored and j < len(values) and values[j] not in (None, ""):
                out.append(f"{get_column_letter(j + 1)}{number} ({_text(values[j])[:40]!r})")
    return out


def read_sheets(path: Path, raw: bytes, mapping: Mapping) -> tuple[list[Sheet], list[str],
                                                                   list[str]]:
    """The data sheets of the workbook `raw`, a note for each sheet skipped, and a warning for
    each skipped sheet whose name gives a voltage (it looks like data)."""
    openpyxl = _openpyxl(path)
    _check_archive(path, raw)
    wb = _load(openpyxl, path, raw, data_only=True)
    try:
        names = list(wb.sheetnames)
        if not names:
            raise UsageError(f"{path}: the workbook has no sheets")
        if len(names) > MAX_SHEETS:
            raise UsageError(f"{path}: {len(names)} sheets, more than the {MAX_SHEETS} "
                             "rigtool reads from one workbook")
        budget = _Budget(path)
        sheets: list[Sheet] = []
        notes: list[str] = []
        skipped_data: list[str] = []
        for name in names:
            ws = wb[name]
            got = (_read_sheet(ws, name, path, mapping, budget) if hasattr(ws, "iter_rows")
                   else f"sheet {sheet_label(name)}: a chart sheet")
            if isinstance(got, Sheet):
                sheets.append(got)
            elif voltage_from_name(name) is None:
                notes.append(f"{got}: skipped")
            else:
                skipped_data.append(f"{got}: skipped, though its name gives a voltage")
    finally:
        wb.close()
    _refuse_formulas(openpyxl, path, raw, sheets)
    return sheets, notes, skipped_data


def _refuse_formulas(openpyxl: Any, path: Path, raw: bytes, sheets: list[Sheet]) -> None:
    """A usage error naming the cells whose formula has no stored result, if any are used."""
    suspects = [s for s in sheets if s.blank_columns]
    if not suspects:
        return
    wb = _load(openpyxl, path, raw, data_only=False)
    try:
        for sheet in suspects:
            cells = _formula_cells(wb, sheet, path)
            if cells:
                more = len(cells) - MAX_LISTED_FORMULAS
                raise UsageError(
                    f"{path}: sheet {sheet_label(sheet.name)}: cell(s) "
                    f"{', '.join(cells[:MAX_LISTED_FORMULAS])}"
                    + (f" and {more} more" if more > 0 else "")
                    + " hold a formula with no stored result (the workbook was saved by a "
                    "program that does not calculate): open and save it in a spreadsheet "
                    "program, or export the sheet as CSV")
    finally:
        wb.close()


def _merge(path: Path, parts: list[tuple[Sheet, Parsed]]) -> Parsed:
    """One Parsed of every data sheet, in sheet order; a field some sheets lack is NaN there."""
    units = {p.command_unit for _, p in parts}
    if len(units) > 1:
        listed = ", ".join(f"{sheet_label(s.name)}: {p.command_unit}" for s, p in parts)
        raise UsageError(f"{path}: the sheets give commands in different units ({listed}): "
                         "import them as separate files, or give --command-unit")
    fields = [f for f in dict.fromkeys(k for _, p in parts for k in p.values)]
    if "time" in fields and any("time" not in p.values for _, p in parts):
        raise UsageError(f"{path}: some sheets have a time column and some do not: import "
                         "them separately")
    values = {f: np.concatenate([p.values.get(f, np.full(p.lines.size, np.nan))
                                 for _, p in parts]) for f in fields}
    first = parts[0][1]
    columns = {f: next(p.columns[f] for _, p in parts if f in p.columns) for f in fields}
    by_text: dict[str, list[str]] = {}
    for s, p in parts:
        for w in p.warnings:
            by_text.setdefault(w, []).append(sheet_label(s.name))
    shown = [f"{'every sheet' if len(where) == len(parts) > 1 else 'sheet ' + ', '.join(where)}: "
             f"{w}" for w, where in by_text.items()]
    return Parsed("xlsx", columns, first.command_unit, values,
                  np.concatenate([p.lines for _, p in parts]),
                  sum(p.n_rows for _, p in parts),
                  [e for _, p in parts for e in p.errors], shown)


def _with_supply(sheet: Sheet, parsed: Parsed, path: Path) -> str:
    """Give every row of the sheet its supply voltage: its own supply column, else the voltage
    in the sheet name; where it came from. A sheet with neither is refused."""
    if "supply" in parsed.values:
        return f"column {parsed.columns['supply'].header!r}"
    if sheet.voltage_v is None:
        raise UsageError(
            f"{path}: sheet {sheet_label(sheet.name)} holds data but its name gives no supply "
            "voltage (one number and a V, like '16 V'): rename the sheet, or add a "
            "`Supply Voltage (V)` column")
    parsed.values["supply"] = np.full(parsed.lines.size, sheet.voltage_v)
    parsed.columns["supply"] = ColumnRef("supply", -1, f"sheet name {sheet_label(sheet.name)}",
                                         "V", 1.0)
    return SUPPLY_FROM_NAME


def read_workbook(path: Path, mapping: Mapping, raw: bytes | None = None) -> WorkbookParsed:
    """Read and parse every data sheet of an .xlsx workbook into one table, each row with the
    supply voltage of its sheet; UsageError for a workbook that cannot be read as one."""
    if raw is None:
        raw = read_regular_bytes(path, MAX_WORKBOOK_BYTES)  # a FIFO or device is refused
    elif len(raw) > MAX_WORKBOOK_BYTES:
        raise UsageError(f"{path}: a workbook of {len(raw):,} bytes, more than the "
                         f"{MAX_WORKBOOK_BYTES >> 20} MiB rigtool reads")
    sheets, notes, skipped = read_sheets(path, raw, mapping)
    if not sheets:
        raise UsageError(f"{path}: no sheet holds a table with command and thrust columns"
                         + (":\n" + "\n".join(notes + skipped) if notes + skipped else ""))
    parts: list[tuple[Sheet, Parsed]] = []
    info: list[dict] = []
    for sheet in sheets:
        parsed = parse(sheet.table, mapping)
        source = _with_supply(sheet, parsed, path)
        parts.append((sheet, parsed))
        supply = parsed.values["supply"]
        levels = np.unique(supply[np.isfinite(supply)]).tolist()
        info.append({"name": sheet.name[:255], "supply_from": source, "supply_v": levels,
                     "header_row": sheet.table.header_line, "rows": parsed.n_rows,
                     "columns": {f: c.header for f, c in parsed.columns.items()}})
    merged = _merge(path, parts)
    if all(i["supply_from"] == SUPPLY_FROM_NAME for i in info):
        merged.columns["supply"] = ColumnRef("supply", -1, "the sheet names", "V", 1.0)
    return WorkbookParsed(merged, hashlib.sha256(raw).hexdigest(), info, notes,
                          skipped + merged.warnings)
