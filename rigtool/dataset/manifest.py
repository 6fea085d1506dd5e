"""The dataset's manifest, `_rigtool_manifest.json` (the leading `_` makes Spark and pyarrow
skip it; DuckDB globs only `*.parquet`): per run the fingerprint it was written from, its
partition file and row count, when and by which rigtool. Read back as hostile (size, shape,
types checked) and written atomically."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

from rigtool.dataset.files import replace_atomically
from rigtool.dataset.partition import DATASET_VERSION
from rigtool.errors import DataError
from rigtool.ids import utc_now
from rigtool.version import __version__

MANIFEST = "_rigtool_manifest.json"
FORMAT = "rigtool-parquet-dataset"
MAX_MANIFEST_BYTES = 256 << 20  # ~2 KB a run: room for 100 000 runs
_TEXT_OR_NONE = (str, type(None))
MAX_COUNT = (1 << 63) - 1  # rows, bytes, points: what an int64 holds


@dataclass
class Entry:
    """One run of the dataset as the manifest records it."""

    thruster_id: str | None
    rig: str | None
    status: str
    fingerprint: dict
    file: str  # the partition file, relative to the dataset folder
    rows: int
    bytes: int
    points: int
    calibrated_utc: str | None
    rigtool_version: str
    written_utc: str
    source: str  # the run database it was last written from
    in_last_source: bool  # False: the database last exported no longer holds (or never held) it


_TYPES = {"thruster_id": _TEXT_OR_NONE, "rig": _TEXT_OR_NONE, "status": str, "fingerprint": dict,
          "file": str, "rows": int, "bytes": int, "points": int,
          "calibrated_utc": _TEXT_OR_NONE, "rigtool_version": str, "written_utc": str,
          "source": str, "in_last_source": bool}


def read_manifest(folder: Path) -> dict[str, Entry] | None:
    """The runs the manifest in `folder` lists; None when there is no manifest. A manifest of
    the wrong size or shape is a DataError naming the file and the field."""
    path = folder / MANIFEST
    if not path.is_file():
        return None
    size = path.stat().st_size
    if size > MAX_MANIFEST_BYTES:
        raise _damaged(path, f"{size:,} bytes; the limit is {MAX_MANIFEST_BYTES:,}")
    try:
        data = json.loads(path.read_bytes())
    except (ValueError, RecursionError) as exc:
        raise _damaged(path, f"not JSON ({str(exc)[:80]})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise _damaged(path, f"not a {FORMAT} manifest")
    version = data.get("dataset_version")
    if not isinstance(version, int) or isinstance(version, bool) or not 1 <= version <= (
            DATASET_VERSION):
        raise _damaged(path, f"dataset_version {str(version)[:20]!r}: this rigtool writes and "
                             f"reads 1..{DATASET_VERSION} (a newer rigtool wrote it?)")
    runs = data.get("runs")
    if not isinstance(runs, dict):
        raise _damaged(path, "`runs` is not an object")
    return {run_id: _entry(path, run_id, fields) for run_id, fields in runs.items()}


def _entry(path: Path, run_id: str, fields: object) -> Entry:
    if not isinstance(fields, dict) or set(fields) != set(_TYPES):
        raise _damaged(path, f"run {run_id[:80]!r}: fields are not {sorted(_TYPES)}")
    for name, kind in _TYPES.items():
        value = fields[name]
        if not isinstance(value, kind) or (kind is int and (isinstance(value, bool)
                                                            or not 0 <= value <= MAX_COUNT)):
            raise _damaged(path, f"run {run_id[:80]!r}, {name}: {str(value)[:80]!r}")
    return Entry(**fields)


def write_manifest(folder: Path, runs: dict[str, Entry], schema: dict[str, str],
                   dataset_version: int) -> None:
    """Replace the manifest atomically: a reader sees the old one or the new one."""
    data = {"format": FORMAT, "dataset_version": dataset_version, "rigtool_version": __version__,
            "written_utc": utc_now(), "table": "samples",
            "partitioning": ["thruster_id", "run_id"], "schema": schema,
            "runs": {run_id: asdict(runs[run_id]) for run_id in sorted(runs)}}
    text = json.dumps(data, indent=1, sort_keys=False, allow_nan=False)
    replace_atomically(folder / MANIFEST, lambda tmp: tmp.write_text(text, encoding="utf-8"))


def _damaged(path: Path, problem: str) -> DataError:
    return DataError(f"dataset manifest {path}: {problem} (the file is damaged or was edited; "
                     "export to a new folder)")
