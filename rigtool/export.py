"""`rigtool export`: a run's points, samples and events as CSV or Parquet; `--all`: every run
of a database as one Parquet dataset (docs/sql.md).

Every table starts with run_id, thruster_id and rig, so files from many runs and rigs stack;
the other column names are the Python API's. Parquet is built from numpy columns, zstd
compressed, with missing values as nulls and the run record in the schema metadata. Samples
are streamed in chunks, so memory does not grow with the run.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from rigtool.analysis.results import DEEP_DEPTH_M
from rigtool.api import deepest_depth, middle_voltage
from rigtool.artefacts.encode import csv_safe_text
from rigtool.artefacts.write import atomic_write
from rigtool.errors import UsageError
from rigtool.outpaths import inside, safe_component
from rigtool.store import MISSING_INT, RunRecord, Store

FORMATS = ("csv", "parquet")
TABLES = ("points", "samples", "events")
KEY_COLUMNS = ("run_id", "thruster_id", "rig")
TEXT_COLUMNS = frozenset({*KEY_COLUMNS, "command_unit", "direction", "status", "kind",
                          "detail_json", "name", "created_utc", "finished_utc", "tool_version",
                          "metadata_json", "protocol_json", "unit", "coefficient", "out_dir",
                          "role"})
Chunk = dict[str, np.ndarray]


def export_run(store: Store, run_id: str, out_dir: Path, fmt: str = "csv") -> list[Path]:
    """Write <run>-points, <run>-samples and <run>-events files into `out_dir`; return them."""
    if fmt not in FORMATS:
        raise UsageError(f"unknown export format {fmt!r}; choose {' or '.join(FORMATS)}")
    written = []
    with store.snapshot():  # points, samples and events of one moment, even mid-sweep
        store.check_run(run_id)  # a damaged run is refused before any file is written
        out_dir.mkdir(parents=True, exist_ok=True)
        record = store.run_record(run_id)
        for table in TABLES:
            path = inside(out_dir, f"{run_id}-{table}.{fmt}")
            chunks = _table(store, record, table)
            if fmt == "csv":
                atomic_write(path, lambda p, chunks=chunks: _write_csv(p, chunks))
            else:
                atomic_write(path, lambda p, chunks=chunks: _write_parquet(p, chunks, record))
            written.append(path)
    return written


def export_all(store: Store, out_dir: Path) -> list[Path]:
    """Every run as a Parquet dataset in `out_dir`: runs.parquet, calibrations.parquet and one
    file per run in points/, samples/ and events/. Returns the paths written."""
    written = []
    with store.snapshot():
        records = [store.run_record(r) for r in store.run_ids()]
        for rec in records:
            store.check_run(rec.id)  # a damaged run is refused before any file is written
        for table in TABLES:
            folder = out_dir / table
            folder.mkdir(parents=True, exist_ok=True)
            for rec in records:
                path = inside(folder, f"{safe_component(rec.id)}.parquet")
                chunks = _table(store, rec, table)
                written.append(atomic_write(
                    path, lambda p, c=chunks, r=rec: _write_parquet(p, c, r)))
        written.append(atomic_write(out_dir / "runs.parquet", lambda p: _write_parquet(
            p, [_runs_table(store, records)], None)))
        written.append(atomic_write(out_dir / "calibrations.parquet", lambda p: _write_parquet(
            p, [_calibrations_table(store, records)], None)))
    return written


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


def _runs_table(store: Store, records: list[RunRecord]) -> Chunk:
    counts = {r["id"]: r["n_steps"] for r in store.runs(limit=len(records) or 1)}

    def col(values: list, dtype: object = object) -> np.ndarray:
        return np.array(values, dtype=dtype)

    return {
        "run_id": col([r.id for r in records]),
        "thruster_id": col([r.thruster_id for r in records]),
        "rig": col([r.rig_name for r in records]),
        "name": col([r.name for r in records]),
        "status": col([r.status for r in records]),
        "created_utc": col([r.created_utc for r in records]),
        "finished_utc": col([r.finished_utc for r in records]),
        "command_unit": col([r.command_unit for r in records]),
        "neutral": col([r.neutral for r in records], float),
        "n_planned": col([r.n_planned for r in records], np.int64),
        "n_points": col([counts.get(r.id, 0) for r in records], np.int64),
        "tool_version": col([r.tool_version for r in records]),
        "metadata_json": col([json.dumps(r.metadata) for r in records]),
        "protocol_json": col([json.dumps(r.protocol) for r in records]),
    }


CALIBRATION_COLUMNS = ("run_id", "thruster_id", "rig", "created_utc", "out_dir", "depth_m",
                       "supply_voltage_v", "role", "main_section", "coefficient", "value", "lo",
                       "hi", "unit", "n")
LAW_TERMS = {"k": "C_n_law_k", "b": "C_n_law_b", "k_inverse": "C_n_law_k_inverse"}


def _calibrations_table(store: Store, records: list[RunRecord]) -> Chunk:
    """One row per coefficient of each run's latest calibration (long format): every depth
    and supply-voltage section, then the C_n(U) law terms of a voltage sweep."""
    rows: list[tuple] = []
    for rec in records:
        cal = store.latest_calibration(rec.id)
        if cal is not None:
            keys = (rec.id, rec.thruster_id, rec.rig_name, cal["created_utc"], cal["out_dir"])
            rows += [(*keys, *row) for row in _coefficient_rows(cal["summary"])]
    out = {}
    for i, name in enumerate(CALIBRATION_COLUMNS):
        values = [r[i] for r in rows]
        if name in TEXT_COLUMNS:
            out[name] = np.array(values, dtype=object)
        elif name == "main_section":
            out[name] = np.array(values, dtype=bool)
        elif name == "n":
            out[name] = np.array([MISSING_INT if v is None else v for v in values], np.int64)
        else:
            out[name] = np.array([np.nan if v is None else v for v in values], dtype=float)
    return out


def _coefficient_rows(summary: dict) -> Iterator[tuple]:
    """(depth, voltage, role, main section, coefficient, value, lo, hi, unit, n) of every
    coefficient a stored calibration summary holds."""
    depths = summary.get("depths") or []
    deep = (summary.get("analysis") or {}).get("deep_depth_m")
    deep = DEEP_DEPTH_M if deep is None else deep
    main = _main_section(depths)
    for i, section in enumerate(depths):
        depth = section.get("depth_m")
        head = (depth, section.get("supply_voltage_v"), _role(depth, deep), i == main)
        for name, c in (section.get("coefficients") or {}).items():
            yield (*head, name, *_coefficient(c))
    main_depth = None if main is None else depths[main].get("depth_m")
    for law in summary.get("voltage_laws") or []:
        depth = law.get("depth_m")
        head = (depth, None, _role(depth, deep), main is not None and depth == main_depth)
        for term, name in LAW_TERMS.items():
            if law.get(term) is not None:
                yield (*head, name, *_coefficient(law[term]))


def _main_section(depths: list[dict]) -> int | None:
    """The section the Python API and the vehicle artefacts use by default (the deepest
    depth, the middle supply voltage there); None without sections."""
    if not depths:
        return None
    depth = deepest_depth([d.get("depth_m") for d in depths])
    here = [i for i, d in enumerate(depths) if d.get("depth_m") == depth]
    return here[middle_voltage([depths[i].get("supply_voltage_v") for i in here])]


def _role(depth: float | None, deep_m: float) -> str:
    """`shallow` where the propeller may ventilate (as calibrate decides), else `deep`."""
    return "shallow" if depth is not None and depth < deep_m else "deep"


def _coefficient(c: dict) -> tuple:
    """value, lo, hi, unit and n of a stored coefficient."""
    return c.get("value"), c.get("lo"), c.get("hi"), c.get("unit"), c.get("n")


def _cells(values: np.ndarray) -> list:
    """A column as CSV cells: missing values (NaN, None, MISSING_INT in ints) empty; text
    that a spreadsheet would run as a formula behind a `'` (the writer quotes the rest)."""
    if values.dtype.kind == "f":
        obj = values.astype(object)
        obj[np.isnan(values)] = None
        return obj.tolist()
    if values.dtype.kind == "i":
        obj = values.astype(object)
        obj[values == MISSING_INT] = None
        return obj.tolist()
    return [csv_safe_text(v) if isinstance(v, str) else v for v in values.tolist()]


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
