"""Read a delimited text table: BOM, blank lines, delimiter sniffing, physical line numbers."""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass, field
from pathlib import Path

from rigtool.errors import UsageError
from rigtool.files import MAX_TABLE_BYTES, read_regular_bytes

CANDIDATE_DELIMITERS = (",", ";", "\t")
OLE_MAGIC = b"\xd0\xcf\x11\xe0\xa1\xb1\x1a\xe1"  # Compound File Binary: .xls, .doc


@dataclass
class RawTable:
    """Header cells and data rows, each row with its 1-based line number in the file.

    `bad` holds the rows the CSV reader itself refused (a cell over the field size limit, say),
    each with its line and the reason, so they are reported and counted like unreadable rows.
    """

    path: Path
    header: list[str]
    header_line: int
    rows: list[tuple[int, list[str]]]
    delimiter: str
    bad: list[tuple[int, str]] = field(default_factory=list)


def sniff_delimiter(line: str, decimal: str) -> str:
    """The most frequent of , ; TAB in the header line (never ',' with a comma decimal)."""
    choices = [d for d in CANDIDATE_DELIMITERS if not (decimal == "," and d == ",")]
    best = max(choices, key=line.count)
    return best if line.count(best) else choices[0]


def read_table(path: Path, *, delimiter: str | None = None, decimal: str = ".",
               header_row: int | None = None, raw: bytes | None = None) -> RawTable:
    """Parse `path` (or its bytes `raw`, already read); the header is line `header_row` or the
    first non-blank line."""
    if raw is None:
        raw = read_regular_bytes(path, MAX_TABLE_BYTES)  # a FIFO or device is refused, not read
    if raw.startswith(OLE_MAGIC):
        raise UsageError(f"{path}: an old Excel .xls workbook (or another OLE file), not a text "
                         "table: save it as .xlsx, or export each sheet as CSV")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")
    lines = text.splitlines()
    if header_row is None:
        header_row = next((i + 1 for i, s in enumerate(lines) if s.strip()), 0)
    if not header_row or header_row > len(lines) or not lines[header_row - 1].strip():
        raise UsageError(f"{path}: no header line found (file empty, or header_row points at a blank line)")
    delim = delimiter or sniff_delimiter(lines[header_row - 1], decimal)
    body = "\n".join(lines[header_row - 1:])
    reader = csv.reader(io.StringIO(body, newline=""), delimiter=delim)
    header: list[str] = []
    rows: list[tuple[int, list[str]]] = []
    bad: list[tuple[int, str]] = []
    while True:  # the reader goes on after a row it refused: note the row and carry on
        try:
            for cells in reader:
                if not header:
                    header = [c.strip() for c in cells]
                    while header and not header[-1]:
                        header.pop()
                elif (cells and cells[0].strip()) or any(c.strip() for c in cells):
                    rows.append((header_row + reader.line_num - 1, cells))
            break
        except csv.Error as exc:
            line = header_row + reader.line_num - 1
            if not header:
                raise UsageError(f"{path}:{line}: header cannot be read: {_reason(exc)}") from None
            bad.append((line, _reason(exc)))
    return RawTable(path, header, header_row, rows, delim, bad)


def _reason(exc: csv.Error) -> str:
    """The CSV reader's complaint in the user's terms."""
    if "field larger than field limit" in str(exc):
        return f"a cell is longer than {csv.field_size_limit()} characters"
    return f"not a valid CSV row ({exc})"
