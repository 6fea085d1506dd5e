"""Merging other run databases into this one: each source opened read-only and checked to
have exactly rigtool's schema, every row checked before it is copied, points, samples,
calibrations and events compared across copies by hash; two copies that disagree are a
MergeConflict and nothing is overwritten."""

from __future__ import annotations

import hashlib
import sqlite3
from collections import Counter
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rigtool.errors import DataError, UsageError
from rigtool.ids import is_run_id, run_label
from rigtool.readback import (
    CALIBRATION_COLUMNS,
    EVENT_COLUMNS,
    MAX_EVENT_BYTES,
    MAX_MERGE_RUNS,
    MAX_STORED_CALIBRATIONS,
    MAX_STORED_EVENTS,
    MAX_STORED_POINTS,
    RUN_COLUMNS,
    STEP_COLUMNS,
    show,
)
from rigtool.store.codec import SAMPLE_COLUMNS
from rigtool.store.connection import open_source
from rigtool.store.reader import Reader
from rigtool.store.schema import INSERT_BLOCK, schema_difference

MERGE_MUTABLE = ("status", "finished_utc", "stop_reason", "started_utc", "host", "pid")
CALIBRATION_KEY = ("created_utc", "tool_version", "out_dir", "summary_json", "state")
BLOCKS_OF_RUN = (f"SELECT st.idx, b.chunk, b.n, {', '.join('b.' + c for c in SAMPLE_COLUMNS[1:])} "
                 "FROM sample_blocks b JOIN steps st ON st.id = b.step_id WHERE st.run_id = ? "
                 "ORDER BY st.idx, b.chunk")


class MergeConflict(DataError):
    """Two copies of a run disagree on something both hold; nothing is merged."""


@dataclass
class RunChange:
    """What a merge brought to one run: points, run record, calibrations and events."""

    run_id: str
    points: int = 0
    status: tuple[str, str] | None = None  # (before, after) when the status changed
    record: bool = False  # status, finish or resume time taken from the source
    calibrations: int = 0
    events: int = 0
    events_replaced: int = 0  # events of a kind a newer calibration rewrote

    @property
    def changed(self) -> bool:
        """Whether the merge changed anything of the run."""
        return any((self.points, self.record, self.calibrations, self.events,
                    self.events_replaced))

    def describe(self) -> str:
        """One line: `+3 point(s), status interrupted -> completed, +1 calibration(s)`."""
        parts = [f"+{self.points} point(s)"] if self.points else []
        if self.status:
            parts.append(f"status {self.status[0]} -> {self.status[1]}")
        elif self.record:
            parts.append("run record updated (resumed)")
        parts += [f"+{n} {what}" for n, what in ((self.calibrations, "calibration(s)"),
                                                   (self.events, "event(s)")) if n]
        if self.events_replaced:
            parts.append(f"{self.events_replaced} event(s) of an older calibration replaced")
        return ", ".join(parts)


@dataclass
class MergeReport:
    """What merging one source did, by run id."""

    added: list[str] = field(default_factory=list)
    updated: list[RunChange] = field(default_factory=list)
    present: list[str] = field(default_factory=list)  # nothing new in the source
    running: list[str] = field(default_factory=list)  # still running in the source
    busy: list[str] = field(default_factory=list)  # running in the target: left alone


def _run_time(run: dict) -> tuple[str, str]:
    """When a run was last started and when it ended: the later copy of a run is ahead."""
    return run["started_utc"] or "", run["finished_utc"] or ""


def _point_fields(step: dict) -> list:
    """A stored point's values but its row id and run id, in STEP_COLUMNS order."""
    return [step[n] for n in STEP_COLUMNS if n not in ("id", "run_id")]


def _event_key(event: dict) -> list:
    """What identifies an event across copies of a run (its row id does not)."""
    return [event["kind"], event["t_s"], event["step_idx"], event["detail_json"]]


def _feed(digest: Any, values: Iterable[object]) -> None:
    """Add SQL values to a hash, tagged by type and length so no two rows collide."""
    for value in values:
        if value is None:
            digest.update(b"n;")
        elif isinstance(value, bytes):
            digest.update(b"b%d;" % len(value))
            digest.update(value)
        elif isinstance(value, str):
            data = value.encode("utf-8")
            digest.update(b"s%d;" % len(data))
            digest.update(data)
        else:
            digest.update(f"{type(value).__name__}:{value!r};".encode())


def _digest(values: Iterable[object]) -> bytes:
    """The SHA-256 of a row's values."""
    digest = hashlib.sha256()
    _feed(digest, values)
    return digest.digest()


def _hexdigest(digest: Any) -> str | None:
    """A running hash's value (None: no blocks)."""
    return None if digest is None else digest.hexdigest()


def _block_digests(conn: sqlite3.Connection, run_id: str) -> dict[int, Any]:
    """Per point of a run in `conn`, the hash of its blocks in chunk order."""
    out: dict[int, Any] = {}
    for idx, *values in conn.execute(BLOCKS_OF_RUN, (run_id,)):
        _feed(out.setdefault(idx, hashlib.sha256()), values)
    return out


def _event_digests(read: Reader, run_id: str) -> dict[str, Counter[bytes]]:
    """Per kind, how many of each event a run holds, by hash."""
    out: dict[str, Counter[bytes]] = {}
    for event in read.rows(run_id, "events", tuple(EVENT_COLUMNS), "run_id = ?", (run_id,),
                           parse=False):
        out.setdefault(event["kind"], Counter())[_digest(_event_key(event))] += 1
    return out


def _insert(conn: sqlite3.Connection, table: str, row: dict, skip: str = "") -> int:
    """Insert a checked row into `main.table` by explicit columns; the new row id."""
    names = [k for k in row if k != skip]
    cur = conn.execute(f"INSERT INTO main.{table} ({', '.join(names)}) VALUES "
                       f"({', '.join('?' * len(names))})", [row[k] for k in names])
    return cur.lastrowid


class MergeSource:
    """A run database to merge from: opened read-only, checked to have exactly rigtool's
    schema, read through explicit column lists, every row checked before it is copied."""

    def __init__(self, path: Path, version: int) -> None:
        self.path = path
        self.conn = open_source(path)
        self.read = Reader(self.conn, f"merge source {path}")
        try:
            self._check_schema(version)
        except BaseException:
            self.conn.close()
            raise

    def close(self) -> None:
        """Close the source; it was never written to."""
        self.conn.close()

    def _check_schema(self, version: int) -> None:
        """Refuse another schema version, a view, a trigger, or any table not rigtool's."""
        try:
            found = self.conn.execute("PRAGMA user_version").fetchone()[0]
            problem = schema_difference(self.conn)
        except sqlite3.DatabaseError as exc:
            raise DataError(f"merge source {self.path}: not a readable SQLite database "
                            f"({exc})") from None
        if found != version:
            raise UsageError(f"{self.path} has schema version {found}, this store {version}: "
                             "open both with the same rigtool first (a writing command such as "
                             "`rigtool calibrate` upgrades an older store)")
        if problem:
            raise DataError(f"merge source {self.path}: {problem}; only the tables rigtool "
                            "makes are merged")

    def copy_into(self, into: Reader, here: set[str]) -> MergeReport:
        """Merge every finished run into the target `into` reads (in its transaction)."""
        report = MergeReport()
        run_id = None
        self.conn.execute("BEGIN")
        try:
            for run_id in self._run_ids():
                self._merge_run(into, run_id, here, report)
        except sqlite3.IntegrityError as exc:
            raise self.read.damaged(run_id, "copying it", str(exc)) from None
        except sqlite3.OperationalError:
            raise
        except sqlite3.DatabaseError as exc:
            raise DataError(f"merge source {self.path}: cannot be read ({exc})") from None
        finally:
            self.conn.execute("ROLLBACK")
        return report

    def _run_ids(self) -> list[str]:
        """The source's run ids, each in the run-id grammar (it names output folders)."""
        self.read.count(None, "runs", "1", (), MAX_MERGE_RUNS)
        self.read.find_bad(None, "runs", ("id",), "1", ())
        ids = [r[0] for r in self.conn.execute("SELECT id FROM runs ORDER BY id")]
        for run_id in ids:
            if not is_run_id(run_id):
                raise self.read.damaged(run_id, "runs.id", "not a run id rigtool makes "
                                        "(YYYYMMDDThhmmssmmmZ-xxxxxx)")
        return ids

    def _merge_run(self, into: Reader, run_id: str, here: set[str], report: MergeReport
                   ) -> None:
        """Add a run the target lacks, or bring what is new of one it has; file the outcome."""
        (run,) = self.read.rows(run_id, "runs", tuple(RUN_COLUMNS), "id = ?", (run_id,),
                                parse=False)
        if run["status"] == "running":
            report.running.append(run_id)
            return
        change = RunChange(run_id)
        if run_id not in here:
            _insert(into.conn, "runs", run)
            here.add(run_id)
            self._merge_contents(into, run_id, change)
            report.added.append(run_id)
            return
        (mine,) = into.rows(run_id, "runs", tuple(RUN_COLUMNS), "id = ?", (run_id,),
                            parse=False)
        if mine["status"] == "running":
            report.busy.append(run_id)
            return
        self._merge_record(into, run, mine, change)
        self._merge_contents(into, run_id, change)
        if change.changed:
            report.updated.append(change)
        else:
            report.present.append(run_id)

    def _conflict(self, into: Reader, run_id: str, where: str, problem: str) -> MergeConflict:
        """The error for a run whose two copies disagree on something both hold."""
        return MergeConflict(f"merge source {self.path}: run {run_label(run_id)}, {where}: "
                             f"{problem} (the two copies of the run disagree, and {into.label} "
                             "is not overwritten)")

    def _merge_record(self, into: Reader, run: dict, mine: dict, change: RunChange) -> None:
        """Take the source's status, finish and resume time when its run ended later."""
        for name in RUN_COLUMNS:
            if name not in MERGE_MUTABLE and run[name] != mine[name]:
                raise self._conflict(into, run["id"], f"runs.{name}",
                                     f"{show(run[name])} here, {show(mine[name])} there")
        if _run_time(run) < _run_time(mine):
            return
        differ = [name for name in MERGE_MUTABLE if run[name] != mine[name]]
        if not differ:
            return
        if _run_time(run) == _run_time(mine):
            raise self._conflict(into, run["id"], f"runs.{differ[0]}",
                                 f"{show(run[differ[0]])} here, {show(mine[differ[0]])} there, "
                                 "for the same start and end time")
        into.conn.execute(f"UPDATE main.runs SET {', '.join(n + ' = ?' for n in MERGE_MUTABLE)} "
                          "WHERE id = ? AND status != 'running'",
                          (*(run[n] for n in MERGE_MUTABLE), run["id"]))
        change.record = True
        if run["status"] != mine["status"]:
            change.status = (mine["status"], run["status"])

    def _merge_contents(self, into: Reader, run_id: str, change: RunChange) -> None:
        """The run's points, samples, calibrations and events the target lacks."""
        change.points = self._merge_points(into, run_id)
        newer = self._merge_calibrations(into, run_id, change)
        self._merge_events(into, run_id, newer, change)

    def _merge_points(self, into: Reader, run_id: str) -> int:
        """Insert the points the target lacks; a point both hold must be the same. Returns
        how many were inserted."""
        self.read.count(run_id, "steps", "run_id = ?", (run_id,), MAX_STORED_POINTS)
        theirs = {row["idx"]: _digest(_point_fields(row)) for row in into.rows(
            run_id, "steps", tuple(STEP_COLUMNS), "run_id = ?", (run_id,), parse=False)}
        new: dict[int, int] = {}
        sizes: dict[int, int] = {}
        for step in self.read.rows(run_id, "steps", tuple(STEP_COLUMNS), "run_id = ?",
                                   (run_id,), "ORDER BY idx", parse=False):
            sizes[step["idx"]] = step["n"]
            if step["idx"] not in theirs:
                new[step["idx"]] = _insert(into.conn, "steps", step, skip="id")
            elif theirs[step["idx"]] != _digest(_point_fields(step)):
                raise self._point_conflict(into, step)
        self._merge_blocks(into, run_id, new, sizes)
        return len(new)

    def _point_conflict(self, into: Reader, step: dict) -> MergeConflict:
        """The error for a point whose stored fields differ from the target's."""
        (mine,) = into.rows(step["run_id"], "steps", tuple(STEP_COLUMNS),
                            "run_id = ? AND idx = ?", (step["run_id"], step["idx"]), parse=False)
        name = next(n for n in STEP_COLUMNS if n != "id" and step[n] != mine[n])
        return self._conflict(into, step["run_id"], f"point {step['idx']}, steps.{name}",
                              f"{show(step[name])} here, {show(mine[name])} there")

    def _merge_blocks(self, into: Reader, run_id: str, new: dict[int, int],
                      sizes: dict[int, int]) -> None:
        """Copy the blocks of the `new` points (idx -> target step id), each adding up to
        its `n`; the blocks of every other point must hash as the target's do."""
        self.read.check_blocks(run_id, "st.run_id = ?", (run_id,))
        held = dict.fromkeys(sizes, 0)
        ours: dict[int, Any] = {}
        for idx, chunk, n, *values in self.conn.execute(BLOCKS_OF_RUN, (run_id,)):
            held[idx] += n
            if idx in new:
                into.conn.execute(INSERT_BLOCK, (new[idx], chunk, n, *values))
            else:
                _feed(ours.setdefault(idx, hashlib.sha256()), (chunk, n, *values))
        for idx, n in sizes.items():
            if held[idx] != n:
                raise self.read.damaged(run_id, f"point {idx}, steps.n",
                                        f"{n:,} samples, but its blocks hold {held[idx]:,}")
        if len(new) < len(sizes):
            theirs = _block_digests(into.conn, run_id)
            for idx in sorted(set(sizes) - set(new)):
                if _hexdigest(ours.get(idx)) != _hexdigest(theirs.get(idx)):
                    raise self._conflict(into, run_id, f"point {idx}, sample_blocks",
                                         "its samples differ from those there")

    def _merge_calibrations(self, into: Reader, run_id: str, change: RunChange) -> bool:
        """Insert the calibrations the target lacks; whether the source's newest is newer
        than every one the target had."""
        self.read.count(run_id, "calibrations", "run_id = ?", (run_id,),
                        MAX_STORED_CALIBRATIONS)
        theirs: Counter[bytes] = Counter()
        newest_theirs = ""
        for cal in into.rows(run_id, "calibrations", CALIBRATION_KEY, "run_id = ?", (run_id,),
                             parse=False):
            theirs[_digest(cal.values())] += 1
            newest_theirs = max(newest_theirs, cal["created_utc"])
        newest_ours = ""
        for cal in self.read.rows(run_id, "calibrations", tuple(CALIBRATION_COLUMNS),
                                  "run_id = ?", (run_id,), "ORDER BY id", parse=False):
            newest_ours = max(newest_ours, cal["created_utc"])
            key = _digest(cal[n] for n in CALIBRATION_KEY)
            if theirs[key]:
                theirs[key] -= 1
                continue
            _insert(into.conn, "calibrations", cal, skip="id")
            change.calibrations += 1
        return newest_ours > newest_theirs

    def _events(self, run_id: str) -> Iterator[dict]:
        """The run's events, each checked (its detail against its kind's shape)."""
        for event in self.read.rows(run_id, "events", tuple(EVENT_COLUMNS), "run_id = ?",
                                    (run_id,), "ORDER BY id", parse=False):
            self.read.detail(run_id, event, EVENT_COLUMNS["detail_json"].check(
                event["detail_json"]))
            yield event

    def _merge_events(self, into: Reader, run_id: str, newer: bool, change: RunChange
                      ) -> None:
        """Insert the events the target lacks. A kind the target holds events of that the
        source does not was rewritten by a calibration (ventilation): the side with the
        newest calibration keeps its events of that kind."""
        self.read.count(run_id, "events", "run_id = ?", (run_id,), MAX_STORED_EVENTS,
                        "detail_json", MAX_EVENT_BYTES)
        theirs = _event_digests(into, run_id)
        ours: dict[str, Counter[bytes]] = {}
        for event in self._events(run_id):
            ours.setdefault(event["kind"], Counter())[_digest(_event_key(event))] += 1
        rewritten = {k for k, held in theirs.items() if held - ours.get(k, Counter())}
        for kind in rewritten if newer else ():
            into.conn.execute("DELETE FROM main.events WHERE run_id = ? AND kind = ?",
                              (run_id, kind))
            change.events_replaced += sum(theirs.pop(kind).values())
        wanted = {k: held - theirs.get(k, Counter()) for k, held in ours.items()
                  if newer or k not in rewritten}
        for event in self._events(run_id) if any(wanted.values()) else ():
            key = _digest(_event_key(event))
            if wanted.get(event["kind"], Counter())[key] > 0:
                wanted[event["kind"]][key] -= 1
                _insert(into.conn, "events", event, skip="id")
                change.events += 1

