"""`_calibrations.pq`: the latest calibration's coefficients of every run in the dataset, one
row per coefficient and section (the columns of `export --all`'s old calibrations table),
gathered from the partition files' footers, so it covers runs exported from every database.
Its name keeps it out of the samples table: no `.parquet` ending, a leading `_`."""

from __future__ import annotations

import json
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from rigtool.dataset.files import replace_atomically
from rigtool.dataset.partition import CALIBRATION_KEYS
from rigtool.errors import DataError

CALIBRATIONS_FILE = "_calibrations.pq"
_TEXT = pa.string()
_TYPES = {"run_id": _TEXT, "thruster_id": _TEXT, "rig": _TEXT, "created_utc": _TEXT,
          "out_dir": _TEXT, "depth_m": pa.float64(), "supply_voltage_v": pa.float64(),
          "role": _TEXT, "main_section": pa.bool_(), "coefficient": _TEXT,
          "value": pa.float64(), "lo": pa.float64(), "hi": pa.float64(), "unit": _TEXT,
          "n": pa.int64()}
SCHEMA = pa.schema(list(_TYPES.items()))


def write_calibrations(folder: Path, files: dict[str, tuple[Path, str | None, str | None]]
                       ) -> None:
    """Rebuild the table from `files` (run id -> partition file, thruster id, rig)."""
    rows: list[list] = []
    for run_id, (path, thruster_id, rig) in sorted(files.items()):
        rows += [[run_id, thruster_id, rig, *row] for row in _stored_rows(path)]
    try:
        table = pa.Table.from_pylist([dict(zip(_TYPES, r, strict=True)) for r in rows],
                                     schema=SCHEMA)
    except (pa.ArrowException, TypeError, ValueError) as exc:
        raise DataError(f"dataset {folder}: a partition's calibration footer holds a value of "
                        f"the wrong type ({str(exc)[:120]}); export to a new folder") from None
    replace_atomically(folder / CALIBRATIONS_FILE,
                       lambda tmp: pq.write_table(table, tmp, compression="zstd"))


def _stored_rows(path: Path) -> list[list]:
    """The coefficient rows a partition file's footer carries, their shape checked."""
    try:
        meta = pq.read_schema(path).metadata or {}
        rows = json.loads(meta.get(b"rigtool_calibration", b"[]"))
    except (OSError, pa.ArrowException, ValueError, RecursionError) as exc:
        raise DataError(f"dataset file {path}: unreadable ({str(exc)[:120]}); export to a new "
                        "folder") from None
    if not isinstance(rows, list) or not all(
            isinstance(r, list) and len(r) == len(CALIBRATION_KEYS) for r in rows):
        raise DataError(f"dataset file {path}: its calibration footer is not rows of "
                        f"{len(CALIBRATION_KEYS)} values; export to a new folder")
    return rows
