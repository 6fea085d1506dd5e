"""Checked reads from one run database (`Reader`), which the store's queries and the merge of
other databases both read through, and the SQL that checks stored sample blocks."""

from __future__ import annotations

import sqlite3
from collections.abc import Iterator, Sequence
from typing import Any

from rigtool.errors import DataError
from rigtool.ids import run_label
from rigtool.readback import (
    CALIBRATION_COLUMNS,
    EVENT_COLUMNS,
    MAX_CHUNK,
    MAX_ID_TEXT,
    MAX_STORED_POINTS,
    RUN_COLUMNS,
    STEP_COLUMNS,
    Column,
    Invalid,
    event_detail,
    show,
)
from rigtool.spool import SAMPLES_PER_CHUNK
from rigtool.store.codec import BLOB_DTYPE, SAMPLE_COLUMNS
from rigtool.store.connection import NotUtf8

TABLES: dict[str, dict[str, Column]] = {
    "runs": RUN_COLUMNS, "steps": STEP_COLUMNS, "events": EVENT_COLUMNS,
    "calibrations": CALIBRATION_COLUMNS,
}
_ROW_KEYS = {"runs": ("id", "run"), "steps": ("idx", "point"), "events": ("id", "event"),
             "calibrations": ("id", "calibration")}
_BLOCK_OK = " AND ".join([
    f"typeof(st.idx) = 'integer' AND st.idx BETWEEN 0 AND {MAX_STORED_POINTS - 1}",
    f"typeof(b.n) = 'integer' AND b.n BETWEEN 0 AND {SAMPLES_PER_CHUNK}",
    f"typeof(b.chunk) = 'integer' AND b.chunk BETWEEN 0 AND {MAX_CHUNK}",
    "(b.n = 0 OR b.t_s IS NOT NULL)",
    *(f"(b.{c} IS NULL OR (typeof(b.{c}) = 'blob' AND length(b.{c}) = "
      f"{BLOB_DTYPE.itemsize} * b.n))" for c in SAMPLE_COLUMNS[1:])])


class Reader:
    """Checked reads from one database: counts, types, ranges and lengths in SQL before
    anything is fetched, JSON texts parsed with bounds and checked for shape after. A
    failure is a DataError naming the database, the run and the field."""

    def __init__(self, conn: sqlite3.Connection, label: str) -> None:
        self.conn = conn
        self.label = label

    def damaged(self, run_id: object, where: str, problem: str) -> DataError:
        """The error for a stored value that fails its check."""
        run = "" if run_id is None else f"run {run_label(run_id)}, "
        return DataError(f"{self.label}: {run}{where}: {problem} (the database is damaged or "
                         "was edited)")

    def count(self, run_id: str, table: str, where: str, args: Sequence, cap: int,
              size_column: str | None = None, max_bytes: int = 0) -> None:
        """Refuse more than `cap` rows, or more than `max_bytes` in all in `size_column`."""
        n, size = self.conn.execute(f"SELECT count(*), total(length({size_column or 'NULL'})) "
                                    f"FROM {table} WHERE {where}", tuple(args)).fetchone()
        if n > cap:
            raise self.damaged(run_id, table, f"{n:,} rows; the limit is {cap:,}")
        if size_column and size > max_bytes:
            raise self.damaged(run_id, f"{table}.{size_column}",
                               f"{int(size):,} bytes in all; the limit is {max_bytes:,}")

    def find_bad(self, run_id: object, table: str, names: Sequence[str], where: str,
                 args: Sequence) -> None:
        """Refuse, before fetching it, a row with a value of the wrong type, range or length."""
        columns = TABLES[table]
        bad = [columns[n].bad_sql(n) for n in names]
        key = _ROW_KEYS[table][0]
        key_sql = f"substr({key}, 1, {MAX_ID_TEXT})" if table == "runs" else _probe(key)
        row = self.conn.execute(
            f"SELECT {', '.join(bad)}, rowid, {key_sql} FROM {table} "
            f"WHERE ({where}) AND ({' OR '.join(bad)}) LIMIT 1", tuple(args)).fetchone()
        if row is not None:
            name = names[row.index(1)]
            run_id = row[-1] if run_id is None and table == "runs" else run_id
            raise self.damaged(run_id, self._field(table, {key: row[-1]}, name),
                               self._problem(table, name, row[-2]))

    def _problem(self, table: str, name: str, rowid: int) -> str:
        """What is wrong with one stored value `find_bad` found, fetched only when small."""
        column = TABLES[table][name]
        size, value = self.conn.execute(
            f"SELECT length({name}), CASE WHEN length({name}) <= {column.length_cap()} THEN "
            f"{name} END FROM {table} WHERE rowid = ?", (rowid,)).fetchone()
        if size is not None and size > column.length_cap():
            if column.kind in ("int", "real"):
                return f"expected a number, found {size:,} characters or bytes"
            return f"{size:,} characters or bytes; the limit is {column.length_cap():,}"
        try:
            column.check(value)
        except Invalid as exc:
            return str(exc)
        return f"{show(value)} is not a value rigtool writes"

    def rows(self, run_id: object, table: str, names: Sequence[str], where: str,
             args: Sequence, order: str = "", parse: bool = True) -> Iterator[dict]:
        """The selected rows as checked dicts (JSON columns parsed when `parse`)."""
        columns = TABLES[table]
        self.find_bad(run_id, table, names, where, args)
        texts = [n for n in names if columns[n].kind == "json"]
        cur = self.conn.execute(f"SELECT {', '.join(names)} FROM {table} WHERE {where} {order}",
                                tuple(args))
        try:
            for values in cur:
                row = dict(zip(names, values, strict=True))
                for name in texts:
                    parsed = self._parsed(run_id, table, row, name)
                    if parse:
                        row[name] = parsed
                yield row
        except NotUtf8 as exc:
            raise self.damaged(run_id, table, exc.problem) from None

    def _parsed(self, run_id: object, table: str, row: dict, name: str) -> Any:
        """A fetched JSON column parsed and checked against its shape."""
        try:
            return TABLES[table][name].check(row[name])
        except Invalid as exc:
            raise self.damaged(run_id, self._field(table, row, name), str(exc)) from None

    @staticmethod
    def _field(table: str, row: dict, name: str) -> str:
        """Where a value sits, for a message: `point 3, steps.command`."""
        key, label = _ROW_KEYS[table]
        if table == "runs" or key not in row:
            return f"{table}.{name}"
        return f"{label} {show(row[key])}, {table}.{name}"

    def listing(self, sql: str, args: Sequence) -> list[dict]:
        """Rows of a query over values already checked, as dicts keyed by column name."""
        try:
            cur = self.conn.execute(sql, tuple(args))
            names = [d[0] for d in cur.description]
            return [dict(zip(names, row, strict=True)) for row in cur]
        except NotUtf8 as exc:
            raise self.damaged(None, "runs", exc.problem) from None

    def detail(self, run_id: str, row: dict, detail: Any) -> Any:
        """An event's parsed detail, checked against the shape its kind needs."""
        try:
            return event_detail(row["kind"], detail)
        except Invalid as exc:
            field = self._field("events", row, "detail_json")
            raise self.damaged(run_id, field, str(exc)) from None

    def check_blocks(self, run_id: str | None, where: str, args: Sequence) -> None:
        """Refuse, before any is decoded, a selected block of a bad count, number or size."""
        row = self.conn.execute(
            "SELECT b.id, substr(st.run_id, 1, ?) FROM sample_blocks b JOIN steps st "
            f"ON st.id = b.step_id WHERE ({where}) AND NOT ({_BLOCK_OK}) LIMIT 1",
            (MAX_ID_TEXT, *args)).fetchone()
        if row is not None:
            raise self.damaged(row[1] if run_id is None else run_id, *self._block_problem(row[0]))

    def _block_problem(self, block_id: int) -> tuple[str, str]:
        """(where, problem) of a block `check_blocks` refused."""
        probes = ", ".join(f"typeof(b.{c}), length(b.{c})" for c in SAMPLE_COLUMNS[1:])
        idx, n, chunk, *sizes = self.conn.execute(
            f"SELECT {_probe('st.idx')}, {_probe('b.n')}, {_probe('b.chunk')}, {probes} "
            "FROM sample_blocks b JOIN steps st ON st.id = b.step_id WHERE b.id = ?",
            (block_id,)).fetchone()
        point = f"point {show(idx)}, block {show(chunk)}"
        for name, value, hi in (("steps.idx", idx, MAX_STORED_POINTS - 1),
                                ("sample_blocks.n", n, SAMPLES_PER_CHUNK),
                                ("sample_blocks.chunk", chunk, MAX_CHUNK)):
            try:
                Column("int", lo=0, hi=hi).check(value)
            except Invalid as exc:
                return f"{point}, {name}", str(exc)
        for c, kind, size in zip(SAMPLE_COLUMNS[1:], sizes[::2], sizes[1::2], strict=True):
            if kind == "null" and c == "t_s" and n > 0:
                return f"{point}, sample_blocks.t_s", f"missing for n = {n:,} samples"
            if kind not in ("null", "blob"):
                return f"{point}, sample_blocks.{c}", f"expected a blob, found {kind}"
            if kind == "blob" and size != BLOB_DTYPE.itemsize * n:
                return (f"{point}, sample_blocks.{c}",
                        f"{size:,} bytes for n = {n:,} samples of {BLOB_DTYPE.itemsize} bytes")
        return point, "not a block rigtool writes"


def _probe(column: str) -> str:
    """SQL giving a column's number as it is, anything else as a short text."""
    return (f"CASE WHEN typeof({column}) IN ('integer', 'real') THEN {column} "
            f"ELSE typeof({column}) || ' ' || quote(substr({column}, 1, 20)) END")

