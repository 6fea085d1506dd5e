"""Read a delimited text table in chunks of rows: BOM, blank lines, delimiter sniffing,
physical line numbers."""

from __future__ import annotations

import codecs
import csv
import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rigtool.errors import UsageError
from rigtool.files import MAX_TABLE_BYTES, iter_regular_bytes

CANDIDATE_DELIMITERS = (",", ";", "\t")
OLE_MAGIC = b"\xd0\xcf\x11\xe0\xa1\xb1\x1a\xe1"  # Compound File Binary: .xls, .doc
MAGIC_BYTES = len(OLE_MAGIC)  # what `scan` keeps of the start of a file
ROWS_PER_CHUNK = 65_536  # rows of text parsed at once: memory holds one chunk of cells


@dataclass
class RawTable:
    """Header cells and data rows, each row with its 1-based line number in the file.

    `bad` holds the rows the CSV reader itself refused (a cell over the field size limit, say),
    each with its line and the reason, so they are reported and counted like unreadable rows.
    `headerless`: the header line held only numbers, so it is the first data row and the
    header is `column 1`, `column 2`, ... (columns can only be given by number).
    """

    path: Path
    header: list[str]
    header_line: int
    rows: list[tuple[int, list[str]]]
    delimiter: str
    bad: list[tuple[int, str]] = field(default_factory=list)
    headerless: bool = False


def sniff_delimiter(line: str, decimal: str) -> str:
    """The most frequent of , ; TAB in the header line (never ',' with a comma decimal)."""
    choices = [d for d in CANDIDATE_DELIMITERS if not (decimal == "," and d == ",")]
    best = max(choices, key=line.count)
    return best if line.count(best) else choices[0]


def is_data_row(cells: list[str], decimal: str) -> bool:
    """Whether a would-be header holds only numbers (and empty cells): a file with no header
    line, whose first line is data."""
    filled = [c.strip() for c in cells if c.strip()]
    for cell in filled:
        try:
            if not math.isfinite(float(cell.replace(",", ".") if decimal == "," else cell)):
                return False
        except ValueError:
            return False
    return bool(filled)


def scan(path: Path) -> tuple[bytes, str]:
    """The first bytes of a text log and the encoding that decodes all of it (UTF-8, a BOM
    dropped; else Latin-1), read block by block: nothing of the file is kept."""
    decoder = codecs.getincrementaldecoder("utf-8-sig")()
    head = b""
    utf8 = True
    for block in iter_regular_bytes(path, MAX_TABLE_BYTES):  # a FIFO or device is refused
        head += block[:MAGIC_BYTES - len(head)]
        try:
            decoder.decode(block)
        except UnicodeDecodeError:
            utf8 = False
            if len(head) == MAGIC_BYTES:
                break  # Latin-1, and the start is known: nothing more to learn
    if utf8:
        try:
            decoder.decode(b"", final=True)
        except UnicodeDecodeError:
            utf8 = False
    if head.startswith(OLE_MAGIC):
        raise UsageError(f"{path}: an old Excel .xls workbook (or another OLE file), not a text "
                         "table: save it as .xlsx, or export each sheet as CSV")
    return head, "utf-8-sig" if utf8 else "latin-1"


def _lines(path: Path, encoding: str, digest: Any) -> Iterator[str]:
    """The file's lines exactly as `str.splitlines` splits the whole text, decoded block by
    block; every byte read goes into `digest`. A line longer than a block is gathered in
    pieces and joined once (linear time however long it is)."""
    decoder = codecs.getincrementaldecoder(encoding)()
    pending: list[str] = []  # the start of a line whose break is not read yet
    tail = ""  # a CR ending a block: LF may follow in the next
    try:
        for block in iter_regular_bytes(path, MAX_TABLE_BYTES):
            digest.update(block)
            text = tail + decoder.decode(block)
            tail = "\r" if text.endswith("\r") else ""
            yield from _split(text[:len(text) - len(tail)], pending)
        yield from _split(tail + decoder.decode(b"", final=True), pending)
    except UnicodeDecodeError:
        raise UsageError(f"{path}: the file changed while it was read") from None
    if pending:
        yield "".join(pending)


def _split(text: str, pending: list[str]) -> Iterator[str]:
    """The lines `text` ends, the first joined to `pending`; an unended last piece goes to
    `pending`."""
    if not text:
        return
    lines = text.splitlines()
    piece = lines.pop() if len((text[-1] + "x").splitlines()) == 1 else None  # no break at the end
    if lines:
        if pending:
            pending.append(lines[0])
            lines[0] = "".join(pending)
            pending.clear()
        yield from lines
    if piece is not None:
        pending.append(piece)


def _body(first: str, rest: Iterator[str]) -> Iterator[str]:
    """The lines from the header on, each but the last ended by LF, as the CSV reader takes them."""
    line = first
    for following in rest:
        yield line + "\n"
        line = following
    yield line


def read_table_chunks(path: Path, *, encoding: str, digest: Any, delimiter: str | None = None,
                      decimal: str = ".", header_row: int | None = None,
                      rows_per_chunk: int | None = None) -> Iterator[RawTable]:
    """Parse `path` (its `encoding` from `scan`) in tables of up to `rows_per_chunk`
    (default ROWS_PER_CHUNK) rows, each with the header; the first is yielded once the header
    is read, even without rows. The header is line `header_row` or the first non-blank line.
    Memory holds one chunk of text."""
    per_chunk = rows_per_chunk or ROWS_PER_CHUNK
    lines = _lines(path, encoding, digest)
    head = None
    for number, line in enumerate(lines, start=1):
        if header_row is None and line.strip():
            header_row = number
        if number == header_row:
            head = line
            break
    if not header_row or head is None or not head.strip():
        raise UsageError(f"{path}: no header line found (file empty, or header_row points at a blank line)")
    delim = delimiter or sniff_delimiter(head, decimal)
    reader = csv.reader(_body(head, lines), delimiter=delim)
    header: list[str] = []
    headerless = False
    rows: list[tuple[int, list[str]]] = []
    bad: list[tuple[int, str]] = []
    while True:  # the reader goes on after a row it refused: note the row and carry on
        try:
            for cells in reader:
                if not header:
                    header = [c.strip() for c in cells]
                    while header and not header[-1]:
                        header.pop()
                    headerless = is_data_row(header, decimal)
                    if headerless:  # no header line: keep the row, number the columns
                        header = [f"column {i}" for i in range(1, len(header) + 1)]
                        rows.append((header_row + reader.line_num - 1, cells))
                elif (cells and cells[0].strip()) or any(c.strip() for c in cells):
                    rows.append((header_row + reader.line_num - 1, cells))
                    if len(rows) >= per_chunk:
                        yield RawTable(path, header, header_row, rows, delim, bad, headerless)
                        rows, bad = [], []
            break
        except csv.Error as exc:
            line = header_row + reader.line_num - 1
            if not header:
                raise UsageError(f"{path}:{line}: header cannot be read: {_reason(exc)}") from None
            bad.append((line, _reason(exc)))
    yield RawTable(path, header, header_row, rows, delim, bad, headerless)


def _reason(exc: csv.Error) -> str:
    """The CSV reader's complaint in the user's terms."""
    if "field larger than field limit" in str(exc):
        return f"a cell is longer than {csv.field_size_limit()} characters"
    return f"not a valid CSV row ({exc})"
