"""`rigtool export RUN`: a run's points, samples and events as CSV or Parquet (`--all`, the
lab's Parquet dataset, is rigtool.dataset).

Every table starts with run_id, thruster_id and rig, so files from many runs and rigs stack;
the other column names are the Python API's. A CSV cell holds a float to FLOAT_DIGITS
significant digits (what a sensor or the clock resolves, without float64's arithmetic noise:
3.949, not 3.9489999999999963); Parquet keeps every float64 exactly. Parquet is built from numpy columns, zstd
compressed, with missing values as nulls and the run record in the schema metadata. Samples
are streamed in chunks, so memory does not grow with the run.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from rigtool.artefacts.encode import csv_safe_text
from rigtool.artefacts.write import write_all
from rigtool.errors import UsageError
from rigtool.outpaths import inside
from rigtool.store import MISSING_INT, RunRecord, Store

FORMATS = ("csv", "parquet")
TABLES = ("points", "samples", "events")
KEY_COLUMNS = ("run_id", "thruster_id", "rig")
TEXT_COLUMNS = frozenset({*KEY_COLUMNS, "command_unit", "direction", "status", "kind",
                          "detail_json", "name", "created_utc", "finished_utc", "tool_version",
                          "metadata_json", "protocol_json", "unit", "coefficient", "out_dir",
                          "role"})
Chunk = dict[str, np.ndarray]
FLOAT_DIGITS = 12  # significant digits of a float in an export CSV (docs/artefacts.md)


def export_run(store: Store, run_id: str, out_dir: Path, fmt: str = "csv") -> list[Path]:
    """Write <run>-points, <run>-samples and <run>-events files into `out_dir`; return them."""
    if fmt not in FORMATS:
        raise UsageError(f"unknown export format {fmt!r}; choose {' or '.join(FORMATS)}")
    with store.snapshot():  # points, samples and events of one moment, even mid-sweep
        store.check_run(run_id)  # a damaged run is refused before any file is written
        out_dir.mkdir(parents=True, exist_ok=True)
        record = store.run_record(run_id)
        writer = _write_csv if fmt == "csv" else (
            lambda path, chunks: _write_parquet(path, chunks, record))
        # all tables or none: a bad sample found late, or a stop, leaves an earlier export whole
        return write_all({
            inside(out_dir, f"{run_id}-{table}.{fmt}"):
                lambda path, table=table: writer(path, _table(store, record, table))
            for table in TABLES})


def _table(store: Store, record: RunRecord, table: str) -> Iterator[Chunk]:
    if table == "points":
        points = store.points(record.id)
        n = len(points["step_idx"])
        chunks: Iterable[Chunk] = [{**points, "command_unit": np.full(n, record.command_unit)}]
    elif table == "samples":
        chunks = _or_empty(store.iter_samples(record.id), store.sample_arrays(record.id, steps=()))
    else:
        events = store.events(record.id)
        chunks = [{
            "t_s": np.array([np.nan if e["t_s"] is None else e["t_s"] for e in events], float),
            "kind": np.array([e["kind"] for e in events], dtype=object),
            "step_idx": np.array([MISSING_INT if e["step_idx"] is None else e["step_idx"]
                                  for e in events], dtype=np.int64),
            "detail_json": np.array([json.dumps(e["detail"]) for e in events], dtype=object),
        }]
    for chunk in chunks:
        yield _with_keys(chunk, record)


def _or_empty(chunks: Iterator[Chunk], empty: Chunk) -> Iterator[Chunk]:
    """The chunks, or one empty chunk (the table's columns) when there are none."""
    any_chunk = False
    for chunk in chunks:
        any_chunk = True
        yield chunk
    if not any_chunk:
        yield empty


def _with_keys(chunk: Chunk, record: RunRecord) -> Chunk:
    n = len(next(iter(chunk.values())))
    keys = {"run_id": record.id, "thruster_id": record.thruster_id, "rig": record.rig_name}
    return {**{k: np.full(n, v, dtype=object) for k, v in keys.items()}, **chunk}


def _cells(values: np.ndarray) -> list:
    """A column as CSV cells: missing values (NaN, None, MISSING_INT in ints) empty; text
    that a spreadsheet would run as a formula behind a `'` (the writer quotes the rest)."""
    if values.dtype.kind == "f":
        return [None if x != x else _float_text(x) for x in values.tolist()]
    if values.dtype.kind == "i":
        obj = values.astype(object)
        obj[values == MISSING_INT] = None
        return obj.tolist()
    return [csv_safe_text(v) if isinstance(v, str) else v for v in values.tolist()]


def _float_text(x: float) -> str:
    """A float to FLOAT_DIGITS significant digits, in its shortest form (never `-0`)."""
    text = f"{x:.{FLOAT_DIGITS}g}"
    return "0" if text == "-0" else text


def _write_csv(path: Path, chunks: Iterator[Chunk]) -> None:
    with path.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh)
        header = False
        for chunk in chunks:
            if not header:
                writer.writerow(chunk)
                header = True
            writer.writerows(zip(*(_cells(v) for v in chunk.values()), strict=True))


def _arrow(name: str, values: np.ndarray) -> object:
    import pyarrow as pa

    if name in TEXT_COLUMNS or values.dtype.kind in "OUS":
        return pa.array(values.tolist(), type=pa.string())
    if values.dtype.kind == "b":
        return pa.array(values, type=pa.bool_())
    if values.dtype.kind == "i":
        return pa.array(values, mask=values == MISSING_INT, type=pa.int64())
    return pa.array(values, mask=np.isnan(values), type=pa.float64())


def _write_parquet(path: Path, chunks: Iterable[Chunk], record: RunRecord | None) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    writer = None
    meta = {} if record is None else {"rigtool_run": json.dumps(record.__dict__, default=str)}
    try:
        for chunk in chunks:
            table = pa.table({k: _arrow(k, v) for k, v in chunk.items()})
            if writer is None:
                writer = pq.ParquetWriter(str(path), table.schema.with_metadata(meta),
                                          compression="zstd")
            writer.write_table(table.replace_schema_metadata(meta))
    finally:
        if writer is not None:
            writer.close()
