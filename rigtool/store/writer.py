"""The single writer: runs, points with their sample blocks, events and calibrations, each
write in one transaction (a crash never leaves half a point), and merging other databases in.
Bulk imports go in batches, so a big import holds the write lock briefly."""

from __future__ import annotations

import itertools
import json
import os
import socket
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from rigtool.errors import UsageError
from rigtool.ids import new_run_id, utc_now
from rigtool.progress_hook import ProgressHook, counted, no_progress
from rigtool.spool import SAMPLES_PER_CHUNK, SampleSpool
from rigtool.store.codec import SAMPLE_COLUMNS, block_row
from rigtool.store.connection import Transaction
from rigtool.store.merge import MergeReport, MergeSource
from rigtool.store.queries import RunQueries
from rigtool.store.records import (
    POINT_STATS,
    RUN_STATUSES,
    STAT_FIELDS,
    StepRecord,
    stat_column,
)
from rigtool.store.schema import INSERT_BLOCK

# Bulk writes (imports): point rows per executemany call, and samples per transaction, so a
# big import holds the write lock briefly and never builds all blocks at once.
BATCH_ROWS = 10_000
IMPORT_ROWS_PER_TRANSACTION = 1_000_000


class RunWriter(RunQueries):
    """The writes of `Store`, each in its own transaction on the open connection `conn`."""

    def transaction(self) -> Transaction:
        """Context manager: BEGIN IMMEDIATE ... COMMIT, or ROLLBACK on error."""
        return Transaction(self.conn, self.path)

    def create_run(
        self,
        *,
        name: str,
        protocol: dict,
        protocol_path: str | None,
        rig: dict,
        plan: list[dict],
        metadata: dict,
        seed: int | None,
        command_unit: str,
        tool_version: str,
        actuator: dict | None = None,
        status: str = "running",
        stop_reason: str | None = None,
    ) -> str:
        """Insert a new run (running, unless an import marks it incomplete until it is done);
        `actuator` is its command space (unit, neutral, range)."""
        if status not in RUN_STATUSES:
            raise ValueError(f"unknown run status {status!r}")
        run_id = new_run_id()
        row = {
            "id": run_id,
            "name": name,
            "status": status,
            "created_utc": utc_now(),
            "finished_utc": None,
            "tool_version": tool_version,
            "host": socket.gethostname(),
            "pid": os.getpid(),
            "seed": seed,
            "protocol_path": protocol_path,
            "protocol_json": json.dumps(protocol),
            "rig_json": json.dumps(rig),
            "plan_json": json.dumps(plan),
            "metadata_json": json.dumps(metadata),
            "n_planned": len(plan),
            "command_unit": command_unit,
            "stop_reason": stop_reason,
            "actuator_json": None if actuator is None else json.dumps(actuator),
            "started_utc": utc_now("microseconds"),
        }
        with self.transaction() as conn:
            conn.execute(f"INSERT INTO runs ({', '.join(row)}) VALUES "
                         f"({', '.join('?' * len(row))})", tuple(row.values()))
        return run_id

    def add_step(
        self,
        run_id: str,
        step: StepRecord,
        samples: dict[str, np.ndarray] | SampleSpool,
    ) -> int:
        """Insert one point and all its samples in a single transaction; return the step id.

        `samples` is a dict of arrays or the engine's SampleSpool; rows go to SQLite in
        blocks, so memory stays bounded however many samples the point has.
        """
        spool = samples if isinstance(samples, SampleSpool) else SampleSpool.of(
            samples, SAMPLE_COLUMNS[1:], STAT_FIELDS)
        fields = dict(step.__dict__)
        counters = fields.pop("counters")
        fields["voltage_set_v"] = fields.pop("voltage_v")
        row: dict[str, Any] = {"run_id": run_id, **fields, "n": spool.n,
                               "counters_json": json.dumps(counters) if counters else None}
        row["settled"] = int(step.settled)
        for name in STAT_FIELDS:
            keys = [stat_column(name, s) for s in POINT_STATS]
            row.update(zip(keys, spool.stats(name) or (None,) * 4, strict=True))
        with self.transaction():
            cur = self.conn.execute(
                f"INSERT INTO steps ({', '.join(row)}) VALUES ({', '.join('?' * len(row))})",
                list(row.values()),
            )
            step_id = cur.lastrowid
            self.conn.executemany(INSERT_BLOCK, (block_row(step_id, k, chunk) for k, chunk
                                                 in enumerate(spool.column_chunks())))
        return step_id

    def add_points(self, run_id: str, points: dict[str, np.ndarray], bounds: np.ndarray,
                   samples: dict[str, np.ndarray], command_unit: str) -> None:
        """Insert many finished points (idx 0, 1, ...) with their samples, for imports.

        Point i owns samples[c][bounds[i]:bounds[i + 1]]; `points` holds the StepRecord fields
        command, depth_m (NaN = none), repeat, direction, t_*_s, settle_s and rate_hz as
        arrays. Points go in with executemany in batches of BATCH_ROWS, in transactions of at
        most IMPORT_ROWS_PER_TRANSACTION samples (one point never splits).
        """
        bounds = np.asarray(bounds, dtype=np.int64)
        n_points = bounds.size - 1
        if n_points and np.any(np.diff(bounds) < 1):
            raise ValueError("every point needs at least one sample")
        columns: dict[str, list] = {k: np.asarray(v).tolist() for k, v in points.items()}
        n = np.diff(bounds)
        columns["n"] = n.tolist()
        for name in STAT_FIELDS:
            stats = segment_stats(samples.get(name), bounds)
            for key, values in stats.items():
                columns[stat_column(name, key)] = values
        start = 0
        while start < n_points:
            limit = bounds[start] + IMPORT_ROWS_PER_TRANSACTION
            stop = min(n_points, max(start + 1, int(np.searchsorted(bounds, limit, "right")) - 1))
            with self.transaction():
                self._insert_points(run_id, columns, bounds, samples, command_unit, start, stop)
            start = stop

    def _insert_points(self, run_id: str, columns: dict[str, list], bounds: np.ndarray,
                       samples: dict[str, np.ndarray], command_unit: str, start: int,
                       stop: int) -> None:
        """Points start..stop-1 and their samples, inside the caller's transaction."""
        first_id = self.conn.execute("SELECT COALESCE(MAX(id), 0) + 1 FROM steps").fetchone()[0]
        filled = {k: v for k, v in columns.items() if any(x is not None for x in v[start:stop])}
        names = ["id", "run_id", "idx", "command_unit", "settled", "status", *filled]
        sql = f"INSERT INTO steps ({', '.join(names)}) VALUES ({', '.join('?' * len(names))})"
        for a in range(start, stop, BATCH_ROWS):
            b = min(stop, a + BATCH_ROWS)
            self.conn.executemany(sql, zip(
                range(first_id + a - start, first_id + b - start), itertools.repeat(run_id),
                range(a, b), itertools.repeat(command_unit), itertools.repeat(1),
                itertools.repeat("ok"), *(values[a:b] for values in filled.values())))
        names = [c for c in SAMPLE_COLUMNS[1:] if samples.get(c) is not None]
        self.conn.executemany(INSERT_BLOCK, (
            block_row(first_id + i - start, k, {
                c: samples[c][a:min(a + SAMPLES_PER_CHUNK, int(bounds[i + 1]))] for c in names})
            for i in range(start, stop)
            for k, a in enumerate(range(int(bounds[i]), int(bounds[i + 1]), SAMPLES_PER_CHUNK))))

    def add_events(self, run_id: str, events: list[tuple[str, dict]]) -> None:
        """Insert several (kind, detail) events of a run in one transaction."""
        with self.transaction():
            self.conn.executemany(
                "INSERT INTO events (run_id, t_s, kind, step_idx, detail_json) "
                "VALUES (?, NULL, ?, NULL, ?)",
                [(run_id, kind, json.dumps(detail)) for kind, detail in events])

    def add_event(
        self, run_id: str, kind: str, detail: dict | None = None,
        t_s: float | None = None, step_idx: int | None = None,
    ) -> None:
        with self.transaction():
            self.conn.execute(
                "INSERT INTO events (run_id, t_s, kind, step_idx, detail_json) VALUES (?, ?, ?, ?, ?)",
                (run_id, t_s, kind, step_idx, json.dumps(detail or {})),
            )

    def finish_run(self, run_id: str, status: str, reason: str | None = None) -> None:
        if status not in RUN_STATUSES:
            raise ValueError(f"unknown run status {status!r}")
        with self.transaction():
            self.conn.execute(
                "UPDATE runs SET status = ?, finished_utc = ?, stop_reason = ? WHERE id = ?",
                (status, utc_now(), reason, run_id),
            )

    def reopen_run(self, run_id: str) -> None:
        """Mark an interrupted/aborted/failed run as running again, owned by this process.

        A single conditional UPDATE, so two resumes of one run cannot both win. The run
        becomes `last` (see `resolve_run_id`).
        """
        with self.transaction():
            cur = self.conn.execute(
                "UPDATE runs SET status = 'running', finished_utc = NULL, stop_reason = NULL, "
                "host = ?, pid = ?, started_utc = ? "
                "WHERE id = ? AND status IN ('interrupted', 'aborted', 'failed')",
                (socket.gethostname(), os.getpid(), utc_now("microseconds"), run_id),
            )
        if cur.rowcount != 1:
            raise UsageError(f"run {run_id} is no longer resumable (another process resumed it?)")

    def add_calibration(self, run_id: str, out_dir: str, summary: dict, tool_version: str,
                        state: bytes | None = None, created_utc: str | None = None) -> None:
        """Record a calibration: its folder, its calibration.json content and (`state`) the
        encoded analysis results that `report` renders."""
        with self.transaction():
            self.conn.execute(
                "INSERT INTO calibrations (run_id, created_utc, tool_version, out_dir, "
                "summary_json, state) VALUES (?, ?, ?, ?, ?, ?)",
                (run_id, created_utc or utc_now(), tool_version, out_dir, json.dumps(summary),
                 state))

    def replace_events(self, run_id: str, kind: str, records: list[dict],
                       t_key: str = "t_start_s", step_key: str = "step_idx") -> None:
        """Replace a run's events of `kind` by `records` in one transaction (a rerun of an
        analysis must not duplicate them)."""
        with self.transaction() as conn:
            conn.execute("DELETE FROM events WHERE run_id = ? AND kind = ?", (run_id, kind))
            conn.executemany(
                "INSERT INTO events (run_id, t_s, kind, step_idx, detail_json) "
                "VALUES (?, ?, ?, ?, ?)",
                [(run_id, r.get(t_key), kind, r.get(step_key), json.dumps(r)) for r in records])

    def merge_from(self, sources: Iterable[str | Path],
                   progress: ProgressHook = no_progress) -> list[MergeReport]:
        """Merge other stores into this one, every row checked first: a run this one lacks is
        copied (run, points under new step ids, samples, events, calibrations); of a run it
        has, what is new is brought over: points it lacks, a later status (a resumed run),
        calibrations and events. A point both hold must be identical (fields, and its sample
        blocks by hash), else MergeConflict; nothing is overwritten. A run still running in
        a source is left for a later merge, one running here is not touched. Merging again
        changes nothing.

        The whole merge is one transaction: any refused row rolls all of it back. Sources
        are opened read-only (immutable when they have no write-ahead log), so not even
        their -wal or -shm files are created. Returns a MergeReport per source; each source
        merged is reported to `progress`.
        """
        opened = []
        try:
            for path in sources:
                opened.append(MergeSource(Path(path), self.version))
            with self.transaction():
                here = set(self.run_ids())
                return [src.copy_into(self._read, here)
                        for src in counted(opened, "databases merged", progress)]
        finally:
            for src in opened:
                src.close()


def segment_stats(values: np.ndarray | None, bounds: np.ndarray) -> dict[str, list]:
    """mean, std (ddof 1; 0 for one value), min and max of the finite values of each segment
    values[bounds[i]:bounds[i + 1]] (None where a segment has none), as `_stats` per point."""
    n_seg = len(bounds) - 1
    if values is None or n_seg == 0:
        return {k: [None] * n_seg for k in ("mean", "std", "min", "max")}
    v = np.asarray(values, dtype=float)
    starts = np.asarray(bounds[:-1], dtype=np.int64)
    seg = np.repeat(np.arange(n_seg), np.diff(bounds))
    finite = np.isfinite(v)
    count = np.bincount(seg, weights=finite, minlength=n_seg)
    good = np.where(finite, v, 0.0)
    mean = np.bincount(seg, weights=good, minlength=n_seg) / np.maximum(count, 1)
    dev = np.where(finite, v - mean[seg], 0.0)
    var = np.bincount(seg, weights=dev * dev, minlength=n_seg) / np.maximum(count - 1, 1)
    std = np.where(count > 1, np.sqrt(var), 0.0)
    low = np.minimum.reduceat(np.where(finite, v, np.inf), starts)
    high = np.maximum.reduceat(np.where(finite, v, -np.inf), starts)
    out = {}
    for key, arr in (("mean", mean), ("std", std), ("min", low), ("max", high)):
        obj = arr.astype(object)
        obj[count == 0] = None
        out[key] = obj.tolist()
    return out
