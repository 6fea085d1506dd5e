"""Notebook displays of the Python API's objects: short text reprs and escaped HTML tables
(`_repr_html_`, as pandas and xarray give), bounded so that a large table shows its size and
a few rows, never every value."""

from __future__ import annotations

import html
import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

HEAD_ROWS = 5  # rows shown from each end of a long table
MAX_COLUMNS = 40  # columns shown before the rest are counted
MAX_CELL = 80  # characters of one cell, then an ellipsis
STYLE = ("<style>.rigtool-display td, .rigtool-display th {text-align: right; "
         "padding: 1px 6px; font-variant-numeric: tabular-nums}</style>")


def cell_text(value: Any) -> str:
    """A value as one short line of text: numbers to 6 significant digits, long text cut."""
    if isinstance(value, (bool, np.bool_)):
        text = str(bool(value))
    elif isinstance(value, (int, np.integer)):
        text = str(int(value))
    elif isinstance(value, (float, np.floating)):
        text = "NaN" if math.isnan(value) else f"{float(value):.6g}"
    elif isinstance(value, np.ndarray):
        text = f"array({value.size})"
    else:
        text = str(value)
    text = " ".join(text.split())
    return text if len(text) <= MAX_CELL else text[:MAX_CELL - 1] + "…"


def escaped(value: Any) -> str:
    """`cell_text(value)` escaped for HTML text and attributes."""
    return html.escape(cell_text(value), quote=True)


def _row_numbers(n_rows: int, head: int) -> list[int | None]:
    """Row indices shown, `head` from each end (None: the gap of the rows left out)."""
    if n_rows <= 2 * head:
        return list(range(n_rows))
    return [*range(head), None, *range(n_rows - head, n_rows)]


def grid_html(caption: str, names: Sequence[str], cell: Any, n_rows: int,
              head: int = HEAD_ROWS) -> str:
    """An HTML table of `n_rows` rows: `cell(row, name)` gives a value; only `head` rows from
    each end and MAX_COLUMNS columns are shown, and the caption says the full size."""
    shown = list(names[:MAX_COLUMNS])
    more = len(names) - len(shown)
    header = "".join(f"<th>{escaped(n)}</th>" for n in shown) + ("<th>…</th>" if more else "")
    rows = []
    for i in _row_numbers(n_rows, head):
        if i is None:
            cells = "".join("<td>…</td>" for _ in shown)
            rows.append(f"<tr><th>…</th>{cells}{'<td></td>' if more else ''}</tr>")
            continue
        cells = "".join(f"<td>{escaped(cell(i, n))}</td>" for n in shown)
        rows.append(f"<tr><th>{i}</th>{cells}{'<td>…</td>' if more else ''}</tr>")
    size = f"{n_rows} rows × {len(names)} columns" + (f" ({more} not shown)" if more else "")
    return (f'{STYLE}<table class="rigtool-display"><caption>{html.escape(caption)}: {size}'
            f"</caption><thead><tr><th></th>{header}</tr></thead><tbody>{''.join(rows)}"
            "</tbody></table>")


def columns_html(caption: str, columns: Mapping[str, Any]) -> str:
    """A column table (name -> array, one length) as a bounded HTML table."""
    names = list(columns)
    n_rows = len(columns[names[0]]) if names else 0
    return grid_html(caption, names, lambda i, n: columns[n][i], n_rows)


def records_html(caption: str, records: Sequence[Mapping[str, Any]],
                 head: int = HEAD_ROWS) -> str:
    """A list of dicts as a bounded HTML table, the keys of every record as columns."""
    names = list(dict.fromkeys(k for r in records for k in r))
    return grid_html(caption, names, lambda i, n: records[i].get(n, ""), len(records), head)


def columns_repr(kind: str, columns: Mapping[str, Any]) -> str:
    """One short line: the table's size and its first column names."""
    names = list(columns)
    n_rows = len(columns[names[0]]) if names else 0
    return f"<rigtool {kind}: {n_rows} rows × {len(names)} columns{_names(names)}>"


def records_repr(kind: str, records: Sequence[Mapping[str, Any]]) -> str:
    """One short line: the number of records and their keys."""
    names = list(dict.fromkeys(k for r in records for k in r))
    return f"<rigtool {kind}: {len(records)} rows{_names(names)}>"


def _names(names: Sequence[str], most: int = 6) -> str:
    if not names:
        return ""
    shown = ", ".join(cell_text(n) for n in names[:most])
    return f": {shown}" + (", …" if len(names) > most else "")


def fields_html(title: str, fields: Iterable[tuple[str, Any]], *extra: str) -> str:
    """A titled two-column table of (label, value), then `extra` HTML blocks (already
    escaped)."""
    rows = "".join(f"<tr><th style='text-align:left'>{escaped(k)}</th>"
                   f"<td style='text-align:left'>{escaped(v)}</td></tr>" for k, v in fields)
    return (f'{STYLE}<div class="rigtool-display"><strong>{html.escape(title)}</strong>'
            f"<table>{rows}</table>{''.join(extra)}</div>")


def interval_text(value: float, lo: float, hi: float, unit: str) -> str:
    """`value [lo, hi] unit`, the interval left out when it is NaN."""
    span = "" if math.isnan(lo) and math.isnan(hi) else f" [{lo:.6g}, {hi:.6g}]"
    return f"{cell_text(value)}{span} {unit}".rstrip()
