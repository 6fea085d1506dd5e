"""The SQLite run store, the only part of rigtool that speaks SQL.

Fixed tables (runs, steps, sample_blocks, events, calibrations) in WAL mode; the schema
version lives in PRAGMA user_version. A point's samples are stored as column BLOBs
(little-endian float64, NaN for a missing value, NULL for an absent channel) in blocks of
at most SAMPLES_PER_CHUNK, inserted with the step they belong to in one transaction, so a
crash never leaves half a point. docs/performance.md has the measurements behind the layout.

One job a module: `schema` (tables and named migrations), `connection` (opening, WAL,
transactions), `codec` (the sample BLOBs), `reader` (checked reads), `queries` and `writer`
(what `Store` reads and writes), `merge` (other databases in), `liveness` (dead sweeps),
`records` (the typed records), `front` (`Store`).
"""

from rigtool.store.codec import BLOB_DTYPE, MISSING_INT, SAMPLE_COLUMNS
from rigtool.store.front import Store
from rigtool.store.liveness import owner_gone
from rigtool.store.merge import MergeConflict, MergeReport, RunChange
from rigtool.store.records import POINT_COLUMNS, RUN_STATUSES, STAT_FIELDS, RunRecord, StepRecord
from rigtool.store.schema import MIGRATIONS, SCHEMA_V1, SCHEMA_VERSION, create_schema
from rigtool.store.writer import segment_stats

__all__ = [
    "BLOB_DTYPE", "MIGRATIONS", "MISSING_INT", "POINT_COLUMNS", "RUN_STATUSES", "SAMPLE_COLUMNS",
    "SCHEMA_V1", "SCHEMA_VERSION", "STAT_FIELDS", "MergeConflict", "MergeReport", "RunChange",
    "RunRecord", "StepRecord", "Store", "create_schema", "owner_gone", "segment_stats",
]
