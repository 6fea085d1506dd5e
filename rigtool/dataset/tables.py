"""The dataset's two small tables beside the samples, gathered from every partition file's
footer (so they cover runs exported from every database) and rewritten when a run changed:
`_tables/runs.pq`, a row per run; `_tables/calibrations.pq`, a row per coefficient of each
run's latest calibration. The folder's leading `_` keeps them out of a pyarrow or Spark read of
the dataset folder, the `.pq` ending out of DuckDB's `**/*.parquet` glob, and the files' own
names are ones Spark opens when named (it drops a file whose name starts with `_` even then).
Earlier datasets had them as `_runs.pq` and `_calibrations.pq`; the next export replaces those."""

from __future__ import annotations

import json
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from rigtool.dataset.calibrations import CALIBRATION_KEYS
from rigtool.dataset.calibrations import SCHEMA as CALIBRATIONS_SCHEMA
from rigtool.dataset.files import partition_dir, replace_atomically
from rigtool.dataset.manifest import Entry
from rigtool.errors import DataError

TABLES_DIR = "_tables"
RUNS_FILE = f"{TABLES_DIR}/runs.pq"  # relative to the dataset folder
CALIBRATIONS_FILE = f"{TABLES_DIR}/calibrations.pq"
OLD_TABLE_FILES = ("_runs.pq", "_calibrations.pq")  # their names before Spark had to read them
_TEXT = pa.string()
RUNS_SCHEMA = pa.schema([
    ("run_id", _TEXT), ("thruster_id", _TEXT), ("rig", _TEXT), ("name", _TEXT),
    ("status", _TEXT), ("created_utc", _TEXT), ("finished_utc", _TEXT), ("stop_reason", _TEXT),
    ("command_unit", _TEXT), ("neutral", pa.float64()), ("n_planned", pa.int64()),
    ("n_points", pa.int64()), ("n_samples", pa.int64()), ("calibrated_utc", _TEXT),
    ("tool_version", _TEXT), ("metadata_json", _TEXT), ("protocol_json", _TEXT),
    ("written_utc", _TEXT), ("in_last_source", pa.bool_())])
_FROM_RECORD = ("name", "created_utc", "finished_utc", "stop_reason", "command_unit", "neutral",
                "n_planned", "tool_version")


def write_tables(folder: Path, runs: dict[str, tuple[Path, Entry]]) -> None:
    """Rebuild both tables from `runs` (run id -> its partition file and manifest entry)."""
    run_rows, cal_rows = [], []
    for run_id, (path, entry) in sorted(runs.items()):
        record, calibration = _footer(path)
        run_rows.append({
            "run_id": run_id, "thruster_id": entry.thruster_id, "rig": entry.rig,
            "status": entry.status, **{k: record.get(k) for k in _FROM_RECORD},
            "n_points": entry.points, "n_samples": entry.rows,
            "calibrated_utc": entry.calibrated_utc,
            "metadata_json": json.dumps(record.get("metadata")),
            "protocol_json": json.dumps(record.get("protocol")),
            "written_utc": entry.written_utc, "in_last_source": entry.in_last_source})
        cal_rows += [dict(zip(CALIBRATIONS_SCHEMA.names, [run_id, entry.thruster_id, entry.rig,
                                                          *row], strict=True))
                     for row in calibration]
    partition_dir(folder, TABLES_DIR)  # made if missing; a symlink is refused
    for name, rows, schema in ((RUNS_FILE, run_rows, RUNS_SCHEMA),
                               (CALIBRATIONS_FILE, cal_rows, CALIBRATIONS_SCHEMA)):
        try:
            table = pa.Table.from_pylist(rows, schema=schema)
        except (pa.ArrowException, TypeError, ValueError, OverflowError) as exc:
            raise DataError(f"dataset {folder}: a partition file's footer holds a value of the "
                            f"wrong type for {name} ({str(exc)[:120]}); delete that partition "
                            "folder and export again") from None
        replace_atomically(folder / name, lambda tmp, t=table: pq.write_table(
            t, tmp, compression="zstd"))


def _footer(path: Path) -> tuple[dict, list[list]]:
    """The run record and calibration rows a partition file's footer carries, checked."""
    try:
        meta = pq.read_schema(path).metadata or {}
        record = json.loads(meta.get(b"rigtool_run", b"{}"))
        rows = json.loads(meta.get(b"rigtool_calibration", b"[]"))
    except (OSError, pa.ArrowException, ValueError, RecursionError) as exc:
        raise DataError(f"dataset file {path}: unreadable ({str(exc)[:120]}); delete its "
                        "partition folder and export again") from None
    if not isinstance(record, dict) or not isinstance(rows, list) or not all(
            isinstance(r, list) and len(r) == len(CALIBRATION_KEYS) for r in rows):
        raise DataError(f"dataset file {path}: its footer is not a run record and rows of "
                        f"{len(CALIBRATION_KEYS)} calibration values; delete its partition "
                        "folder and export again")
    return record, rows
