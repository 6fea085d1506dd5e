"""The sample BLOB codec: a point's samples as column blocks of little-endian float64 (NaN for
a missing value, NULL for an absent channel), at most SAMPLES_PER_CHUNK samples a block, and
back to numpy columns, every block's count and size checked before anything is allocated."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

from rigtool.errors import DataError
from rigtool.readback import show
from rigtool.spool import SAMPLES_PER_CHUNK

SAMPLE_COLUMNS = (
    "step_id", "t_s", "fx", "fy", "fz", "tx", "ty", "tz",
    "thrust_n", "speed_rpm", "current_a", "voltage_v", "command", "seq",
)
INT_SAMPLE_COLUMNS = ("step_idx", "seq")
MISSING_INT = -1  # an integer column's value where the store has none (seq of old runs)
BLOB_DTYPE = np.dtype("<f8")
MAX_SAMPLE = 1e15  # |any stored sample|: far beyond any reading, exact for integer counters


def encode(values: np.ndarray | None) -> bytes | None:
    """A column block as little-endian float64 bytes; None (NULL) when it holds no value."""
    if values is None:
        return None
    array = np.ascontiguousarray(values, dtype=BLOB_DTYPE)
    return None if np.isnan(array).all() else array.tobytes()


def block_row(step_id: int, chunk: int, columns: dict[str, np.ndarray | None]) -> tuple:
    """The schema.INSERT_BLOCK parameters of one block of a point's samples (t_s is required)."""
    n = len(columns["t_s"])
    return (step_id, chunk, n, *(encode(columns.get(c)) for c in SAMPLE_COLUMNS[1:]))


def decode(blob: bytes | None, n: int, column: str, path: Path) -> np.ndarray:
    """One stored column block as float64 (an absent channel: NaN), its count and size
    checked before anything is allocated, its values after (a crafted inf or 1e308 would
    reach the fits); `path` is the run database a DataError names."""
    if isinstance(n, bool) or not isinstance(n, int) or not 0 <= n <= SAMPLES_PER_CHUNK:
        raise DataError(f"run database {path}: a block of column {column} claims "
                        f"{show(n)} samples (0 .. {SAMPLES_PER_CHUNK:,} allowed); the file "
                        "is damaged")
    if blob is None:
        return np.full(n, np.nan)
    if not isinstance(blob, bytes) or len(blob) != n * BLOB_DTYPE.itemsize:
        raise DataError(f"run database {path}: a block of column {column} holds "
                        f"{show(blob)} for {n} samples; the file is damaged")
    values = np.frombuffer(blob, dtype=BLOB_DTYPE)
    if n and values.min() >= -MAX_SAMPLE and values.max() <= MAX_SAMPLE:
        return values  # the usual block: two passes, no temporary (a NaN fails both tests)
    magnitude = np.abs(values)  # NaN is a missing value, except in t_s
    bad = ~(magnitude <= MAX_SAMPLE) if column == "t_s" else magnitude > MAX_SAMPLE
    if bad.any():
        raise DataError(f"run database {path}: a block of column {column} holds a sample of "
                        f"{show(float(values[np.argmax(bad)]))} (finite, within "
                        f"+-{MAX_SAMPLE:g}{', never NaN' if column == 't_s' else ''}); the "
                        "file is damaged")
    return values


def decode_blocks(blocks: list[tuple], cols: list[str], path: Path) -> dict[str, np.ndarray]:
    """Rows (step idx, n, BLOB per column) decoded into columns, ints as INT_SAMPLE_COLUMNS."""
    out = {"step_idx": np.repeat(np.array([b[0] for b in blocks], dtype=np.int64),
                                 [b[1] for b in blocks])}
    for i, c in enumerate(cols[1:], start=2):
        values = np.concatenate([decode(b[i], b[1], c, path) for b in blocks]) if blocks \
            else np.empty(0)
        if c in INT_SAMPLE_COLUMNS:
            values = np.where(np.isnan(values), MISSING_INT, values).astype(np.int64)
        out[c] = values
    return out


def checked_columns(columns: Iterable[str]) -> list[str]:
    """`columns` as a list, refused (ValueError) when one is not a sample column."""
    cols = list(columns)
    bad = set(cols) - set(SAMPLE_COLUMNS)
    if bad:
        raise ValueError(f"unknown sample columns {sorted(bad)}")
    return cols


def sample_names(columns: Iterable[str] | None) -> list[str]:
    """`step_idx` then the asked sample columns (all of them for None), checked."""
    cols = ["step_idx", *(c for c in (columns or SAMPLE_COLUMNS[1:]) if c != "step_idx")]
    checked_columns(cols[1:])
    return cols
