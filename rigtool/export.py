"""Export a run's samples, points and events as CSV or Parquet for other tools.

CSV is streamed straight from SQLite (constant memory for million-sample runs);
Parquet goes through pyarrow in step-sized batches.
"""

from __future__ import annotations

import csv
from collections.abc import Iterator
from pathlib import Path

from rigtool.errors import UsageError
from rigtool.outpaths import inside
from rigtool.store import SAMPLE_COLUMNS, Store

POINT_COLUMNS = (
    "idx", "command", "command_unit", "depth_m", "repeat", "direction", "t_start_s",
    "t_acquire_s", "t_end_s", "settle_s", "settled", "rate_hz", "status", "n",
    "thrust_n_mean", "thrust_n_std", "thrust_n_min", "thrust_n_max",
    "speed_rpm_mean", "speed_rpm_std", "speed_rpm_min", "speed_rpm_max",
    "current_a_mean", "current_a_std", "current_a_min", "current_a_max",
)
SAMPLE_EXPORT_COLUMNS = ("step_idx", *SAMPLE_COLUMNS[1:])
EVENT_COLUMNS = ("t_s", "kind", "step_idx", "detail_json")
FORMATS = ("csv", "parquet")


def _queries(run_id: str) -> dict[str, tuple[tuple[str, ...], str, tuple]]:
    sample_cols = ", ".join(f"s.{c}" for c in SAMPLE_COLUMNS[1:])
    return {
        "points": (POINT_COLUMNS, f"SELECT {', '.join(POINT_COLUMNS)} FROM steps WHERE run_id = ? "
                   "ORDER BY idx", (run_id,)),
        "samples": (SAMPLE_EXPORT_COLUMNS, f"SELECT st.idx, {sample_cols} FROM samples s "
                    "JOIN steps st ON st.id = s.step_id WHERE st.run_id = ? ORDER BY s.rowid",
                    (run_id,)),
        "events": (EVENT_COLUMNS, f"SELECT {', '.join(EVENT_COLUMNS)} FROM events WHERE run_id = ? "
                   "ORDER BY id", (run_id,)),
    }


def _batches(store: Store, sql: str, args: tuple, size: int = 50_000) -> Iterator[list[tuple]]:
    cur = store.conn.execute(sql, args)
    while rows := cur.fetchmany(size):
        yield rows


def export_run(store: Store, run_id: str, out_dir: Path, fmt: str = "csv") -> list[Path]:
    """Write <run>-points, <run>-samples and <run>-events files into `out_dir`; return them."""
    if fmt not in FORMATS:
        raise UsageError(f"unknown export format {fmt!r}; choose {' or '.join(FORMATS)}")
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    with store.snapshot():  # points, samples and events of one moment, even mid-sweep
        for table, (columns, sql, args) in _queries(run_id).items():
            path = inside(out_dir, f"{run_id}-{table}.{fmt}")
            if fmt == "csv":
                _write_csv(path, columns, _batches(store, sql, args))
            else:
                _write_parquet(path, columns, _batches(store, sql, args))
            written.append(path)
    return written


def _write_csv(path: Path, columns: tuple[str, ...], batches: Iterator[list[tuple]]) -> None:
    with path.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh)
        writer.writerow(columns)
        for rows in batches:
            writer.writerows(rows)


TEXT_COLUMNS = {"command_unit", "direction", "status", "kind", "detail_json"}
INT_COLUMNS = {"idx", "step_idx", "repeat", "settled", "n", "seq"}


def _write_parquet(path: Path, columns: tuple[str, ...], batches: Iterator[list[tuple]]) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    def kind(c: str) -> pa.DataType:
        return pa.string() if c in TEXT_COLUMNS else pa.int64() if c in INT_COLUMNS else pa.float64()

    schema = pa.schema([(c, kind(c)) for c in columns])
    with pq.ParquetWriter(path, schema) as writer:
        for rows in batches:
            cols = list(zip(*rows, strict=True))
            writer.write_table(pa.Table.from_arrays(
                [pa.array(col, type=f.type) for col, f in zip(cols, schema, strict=True)],
                schema=schema))
