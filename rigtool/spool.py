"""Hold one point's samples until the store commits them, in bounded memory.

A point may have up to MAX_SAMPLES_PER_POINT samples (about 10 GiB as rows). The spool
keeps the first IN_MEMORY_SAMPLES in memory; beyond that it appends rows to an unlinked
temporary file and keeps running statistics, so memory stays bounded by the block size
whatever the point's length. The store takes the samples back as column chunks.
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

IN_MEMORY_SAMPLES = 250_000  # about 30 MB of rows; larger points spill to disk
SAMPLES_PER_CHUNK = 65_536  # samples per stored block: 512 KiB per float64 column


class _Running:
    """Count, mean, M2, min and max of the finite values seen, merged block by block (Chan)."""

    def __init__(self) -> None:
        self.n, self.mean, self.m2 = 0, 0.0, 0.0
        self.lo, self.hi = math.inf, -math.inf

    def add(self, values: np.ndarray) -> None:
        v = values[np.isfinite(values)]
        if v.size == 0:
            return
        mean = float(v.mean())
        m2 = float(((v - mean) ** 2).sum())
        n = self.n + v.size
        delta = mean - self.mean
        self.mean += delta * v.size / n
        self.m2 += m2 + delta * delta * self.n * v.size / n
        self.n = n
        self.lo, self.hi = min(self.lo, float(v.min())), max(self.hi, float(v.max()))

    def stats(self) -> tuple[float, float, float, float] | None:
        if self.n == 0:
            return None
        std = math.sqrt(self.m2 / (self.n - 1)) if self.n > 1 else 0.0
        return self.mean, std, self.lo, self.hi


class SampleSpool:
    """One point's sample blocks (dicts of equal-length arrays), in memory or spilled."""

    def __init__(self, columns: tuple[str, ...], stat_fields: tuple[str, ...],
                 spill_dir: str | Path | None = None) -> None:
        self.columns = columns
        self.n = 0
        self._blocks: list[dict[str, np.ndarray]] = []
        self._stat_fields = stat_fields
        self._spill_dir = spill_dir
        self._file = None  # unlinked temporary file of float64 rows, once spilled
        self._running: dict[str, _Running] = {}
        self._sums: dict[str, float] = {}

    @classmethod
    def of(cls, samples: dict[str, np.ndarray], columns: tuple[str, ...],
           stat_fields: tuple[str, ...]) -> SampleSpool:
        """A spool holding `samples` (all in memory, as callers with whole points pass them)."""
        spool = cls(columns, stat_fields)
        spool._blocks.append(samples)
        spool.n = len(samples["t_s"])
        return spool

    @property
    def spilled(self) -> bool:
        return self._file is not None

    def add(self, block: dict[str, np.ndarray]) -> None:
        """Append one block; spill everything to disk once IN_MEMORY_SAMPLES is passed."""
        self.n += len(block["t_s"])
        if self._file is None:
            self._blocks.append(block)
            if self.n <= IN_MEMORY_SAMPLES:
                return
            self._file = tempfile.TemporaryFile(dir=self._spill_dir)  # noqa: SIM115 - closed by close()
            held, self._blocks = self._blocks, []
            for b in held:
                self._spill(b)
        else:
            self._spill(block)

    def _spill(self, block: dict[str, np.ndarray]) -> None:
        for name in self._stat_fields:
            if block.get(name) is not None:
                values = np.asarray(block[name], dtype=float)
                self._running.setdefault(name, _Running()).add(values)
                self._sums[name] = self._sums.get(name, 0.0) + float(values.sum())
        self._rows(block).tofile(self._file)

    def _rows(self, block: dict[str, np.ndarray]) -> np.ndarray:
        n = len(block["t_s"])
        matrix = np.empty((n, len(self.columns)))
        for i, c in enumerate(self.columns):
            values = block.get(c)
            matrix[:, i] = np.nan if values is None else values
        return matrix

    def _joined(self, name: str) -> np.ndarray | None:
        parts = [b[name] for b in self._blocks if b.get(name) is not None]
        if len(parts) < len(self._blocks) or not parts:
            return None
        return np.concatenate(parts) if len(parts) > 1 else np.asarray(parts[0])

    def stats(self, name: str) -> tuple[float, float, float, float] | None:
        """(mean, std, min, max) of the finite values of `name`; None when there are none."""
        if self.spilled:
            running = self._running.get(name)
            return running.stats() if running else None
        values = self._joined(name)
        if values is None:
            return None
        v = np.asarray(values, dtype=float)
        v = v[np.isfinite(v)]
        if v.size == 0:
            return None
        std = float(v.std(ddof=1)) if v.size > 1 else 0.0
        return float(v.mean()), std, float(v.min()), float(v.max())

    def mean(self, name: str) -> float | None:
        """Mean of all values of `name` (NaN if any is NaN), for progress reports; once spilled,
        only the stat fields are kept."""
        if self.n == 0:
            return None
        if self.spilled:
            return self._sums[name] / self.n if name in self._sums else None
        values = self._joined(name)
        return None if values is None else float(np.mean(values))

    def column_chunks(self) -> Iterator[dict[str, np.ndarray | None]]:
        """The samples as float64 columns (None: the channel is absent), at most
        SAMPLES_PER_CHUNK at a time, in acquisition order."""
        if not self.spilled:
            joined = {c: self._column(c) for c in self.columns}
            for start in range(0, self.n, SAMPLES_PER_CHUNK):
                yield {c: None if v is None else v[start:start + SAMPLES_PER_CHUNK]
                       for c, v in joined.items()}
            return
        self._file.seek(0)
        width = len(self.columns)
        while True:
            rows = np.fromfile(self._file, count=SAMPLES_PER_CHUNK * width)
            if rows.size == 0:
                return
            rows = rows.reshape(-1, width)
            yield {c: rows[:, i] for i, c in enumerate(self.columns)}

    def _column(self, name: str) -> np.ndarray | None:
        """One in-memory column over all blocks (NaN where a block lacks it); None if none has it."""
        if all(b.get(name) is None for b in self._blocks):
            return None
        parts = [np.full(len(b["t_s"]), np.nan) if b.get(name) is None
                 else np.asarray(b[name], dtype=float) for b in self._blocks]
        return parts[0] if len(parts) == 1 else np.concatenate(parts)

    def close(self) -> None:
        """Drop the samples and delete the spill file."""
        self._blocks = []
        if self._file is not None:
            self._file.close()
            self._file = None
