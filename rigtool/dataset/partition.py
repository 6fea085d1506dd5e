"""One run's partition file: every sample of the run as a row, with its point's columns and
the run's, in the dataset's one schema, written a chunk at a time (memory bounded by
Store.iter_samples' chunk, not the run). The run record and its latest calibration's
coefficients ride in the file's footer metadata."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from rigtool.dataset.calibrations import calibration_rows
from rigtool.errors import DataError
from rigtool.store import MISSING_INT, SAMPLE_COLUMNS, RunRecord, Store

DATASET_VERSION = 1  # the layout and schema below; a new one rewrites every partition
DATA_FILE = "samples.parquet"
RUN_FIELDS = {"rig": pa.string(), "run_status": pa.string(), "command_unit": pa.string()}
# dataset column -> the store's point column (Store.points), repeated on each of its samples
POINT_FIELDS = {"step_idx": ("step_idx", pa.int64()), "point_command": ("command", pa.float64()),
                "depth_m": ("depth_m", pa.float64()),
                "voltage_set_v": ("voltage_set_v", pa.float64()),
                "repeat": ("repeat", pa.int64()), "direction": ("direction", pa.string()),
                "point_status": ("status", pa.string())}
SAMPLE_FIELDS = {c: pa.int64() if c == "seq" else pa.float64() for c in SAMPLE_COLUMNS[1:]}
SCHEMA = pa.schema([*RUN_FIELDS.items(), *((k, t) for k, (_, t) in POINT_FIELDS.items()),
                    *SAMPLE_FIELDS.items()])


def write_partition(store: Store, record: RunRecord, path: Path) -> int:
    """Write the run's samples to `path` as one Parquet file; return the row count."""
    points = store.points(record.id)
    meta = {"rigtool_dataset": json.dumps({"version": DATASET_VERSION}),
            "rigtool_run": json.dumps(record.__dict__, default=str),
            "rigtool_calibration": json.dumps(calibration_rows(store, record.id),
                                              allow_nan=False)}
    schema = SCHEMA.with_metadata(meta)
    rows = 0
    by_point = {k: _arrow(points[src], t) for k, (src, t) in POINT_FIELDS.items()}
    texts = [f.name for f in SCHEMA if f.type == pa.string()]  # dictionaries pay off there
    with pq.ParquetWriter(str(path), schema, compression="zstd", use_dictionary=texts) as writer:
        for chunk in store.iter_samples(record.id):
            writer.write_table(_rows(chunk, points["step_idx"], by_point, record, schema))
            rows += len(chunk["step_idx"])
    return rows


def _rows(chunk: dict[str, np.ndarray], known: np.ndarray, by_point: dict[str, pa.Array],
          record: RunRecord, schema: pa.Schema) -> pa.Table:
    """A chunk of samples as dataset rows: the run's columns, its point's (taken from
    `by_point`, the run's points in the order of `known` step indices), its own."""
    idx = chunk["step_idx"]
    at = np.minimum(np.searchsorted(known, idx), max(len(known) - 1, 0))
    if len(idx) and (len(known) == 0 or (known[at] != idx).any()):
        raise DataError(f"run {record.id}: samples of a point the run does not hold")
    n = len(idx)
    run = {"rig": record.rig_name, "run_status": record.status,
           "command_unit": record.command_unit}
    take = pa.array(at)
    columns = [pa.repeat(pa.scalar(run[k], type=t), n) for k, t in RUN_FIELDS.items()]
    columns += [by_point[k].take(take) for k in POINT_FIELDS]
    columns += [_arrow(chunk[k], t) for k, t in SAMPLE_FIELDS.items()]
    return pa.Table.from_arrays(columns, schema=schema)


def _arrow(values: np.ndarray, kind: pa.DataType) -> pa.Array:
    """A numpy column as Arrow, missing values (NaN, MISSING_INT) as nulls."""
    if kind == pa.string():
        return pa.array(values.tolist(), type=kind)
    if kind == pa.int64():
        return pa.array(values, mask=values == MISSING_INT, type=kind)
    return pa.array(values, mask=np.isnan(values), type=kind)
