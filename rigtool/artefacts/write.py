"""The one way rigtool writes a file (atomically) and the one JSON/CSV convention.

JSON: sorted keys, floats rounded to 10 significant digits, NaN/inf as null, numpy and
dataclasses as plain data. CSV: one header row, then the rows, floats as `%.9g`, missing values
as `nan`, so every reader opens it as a table with its default options; what the file and its
columns mean is in a sidecar `<name>.columns.csv` (column, unit, description). A reader never
sees half a file: each is written beside its target and renamed.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import math
import os
import unicodedata
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rigtool.artefacts.encode import csv_safe_text, scalar_text

MISSING = "nan"


def atomic_write(path: Path, content: str | bytes | Callable[[Path], object]) -> Path:
    """Write `content` (text, bytes, or a function that writes the path it is given) to a
    temporary file beside `path`, then rename it over `path`; return `path`."""
    tmp = path.with_name(path.name + ".tmp")
    try:
        if isinstance(content, str):
            tmp.write_text(content, encoding="utf-8", newline="\n")
        elif isinstance(content, bytes):
            tmp.write_bytes(content)
        else:
            content(tmp)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def write_all(texts: dict[Path, str | Callable[[Path], object]]) -> list[Path]:
    """Write every text (or what a function writes to the path it is given) to its path or
    none: each goes to a temporary file beside its path first, and only when all are written
    (and no path is a directory) are they renamed into place; on a failure or a stop the
    temporary files are removed and the error raised, and files already there stay whole."""
    tmps = {path: path.with_name(path.name + ".tmp") for path in texts}
    try:
        for path, tmp in tmps.items():
            if path.is_dir():
                raise IsADirectoryError(f"{path} is a directory")
            content = texts[path]
            if isinstance(content, str):
                tmp.write_text(content, encoding="utf-8", newline="\n")
            else:
                content(tmp)
    except BaseException:
        for tmp in tmps.values():
            tmp.unlink(missing_ok=True)
        raise
    for path, tmp in tmps.items():
        os.replace(tmp, path)
    return list(texts)


def json_clean(obj: Any, digits: int | None = 10) -> Any:
    """JSON-safe, deterministic copy: numpy and dataclasses to plain data, floats to `digits`
    significant digits (None: exact), NaN/inf to None."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return json_clean(dataclasses.asdict(obj), digits)
    if isinstance(obj, dict):
        return {str(k): json_clean(v, digits) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [json_clean(v, digits) for v in obj]
    if isinstance(obj, np.ndarray):
        return json_clean(obj.tolist(), digits)
    if isinstance(obj, bool | np.bool_):
        return bool(obj)
    if isinstance(obj, int | np.integer):
        return int(obj)
    if isinstance(obj, float | np.floating):
        x = float(obj)
        if not math.isfinite(x):
            return None
        return x if digits is None else float(f"{x:.{digits}g}")
    return obj


def json_text(obj: Any, indent: int | None = 2, digits: int | None = 10) -> str:
    """`obj` as JSON text in the convention above, with a final newline."""
    return json.dumps(json_clean(obj, digits), indent=indent, sort_keys=True,
                      allow_nan=False) + "\n"


def csv_cell(v: object) -> str:
    """One CSV cell: booleans 0/1, floats %.9g (never -0), missing as `nan`; text on one line
    with no comma or double quote (the files are unquoted), never starting like a formula."""
    if isinstance(v, bool | np.bool_):
        return "1" if v else "0"
    if isinstance(v, int | np.integer):
        return str(int(v))
    if isinstance(v, float | np.floating):
        x = float(v)
        if not math.isfinite(x):
            return MISSING
        s = f"{x:.9g}"
        return "0" if s == "-0" else s
    text = " ".join(str(v).replace(",", ";").replace('"', "'").splitlines())
    return csv_safe_text(text)  # a stored text that would run as a spreadsheet formula is defused


def _visible(text: str) -> str:
    """`text` with every control, format (bidi) or private character as a \\u escape: a
    comment shows what it holds and cannot reorder or hide the text around it."""
    return "".join(c if unicodedata.category(c) not in _HIDDEN else f"\\u{ord(c):04x}"
                   for c in text)


_HIDDEN = {"Cc", "Cf", "Co", "Cs", "Zl", "Zp"}


def csv_text(columns: Sequence[tuple[str, str, str]], rows: Iterable[Sequence[object]]) -> str:
    """CSV text: the header row (each name a single cell), then the rows; the columns'
    documentation goes to the sidecar `columns_text` writes."""
    lines = [",".join(csv_cell(name) for name, _, _ in columns)]
    lines += [",".join(csv_cell(v) for v in row) for row in rows]
    return "\n".join(lines) + "\n"


def columns_path(path: Path) -> Path:
    """The sidecar documenting the CSV at `path`: points.csv -> points.columns.csv."""
    return path.with_name(f"{path.stem}.columns.csv")


def columns_text(notes: Sequence[str], columns: Sequence[tuple[str, str, str]]) -> str:
    """A CSV's sidecar: the header `column,unit,description`, a row with an empty column per
    note about the whole file, then a row per column. Cells are quoted where they hold a
    comma or a quote (RFC 4180); each is one line with every hidden character shown as a
    \\u escape, and never starts like a spreadsheet formula."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(["column", "unit", "description"])
    writer.writerows(["", "", _one_line(note)] for note in notes)
    writer.writerows([_one_line(name), _one_line(unit), _one_line(text)]
                     for name, unit, text in columns)
    return buf.getvalue()


def _one_line(text: str) -> str:
    return csv_safe_text(" ".join(_visible(line) for line in scalar_text(str(text)).splitlines()))
