"""The store's queries: runs, points, samples, events, counters and calibrations of a run,
every value checked on the way out (rigtool.store.reader), samples decoded from their blocks
(rigtool.store.codec). `Store` reads through these methods."""

from __future__ import annotations

import contextlib
import sqlite3
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rigtool.counters import TRAFFIC_COUNTERS
from rigtool.errors import UsageError
from rigtool.readback import (
    EVENT_COLUMNS,
    MAX_EVENT_BYTES,
    MAX_STORED_CALIBRATIONS,
    MAX_STORED_EVENTS,
    MAX_STORED_POINTS,
    RUN_COLUMNS,
    STEP_COLUMNS,
    Invalid,
)
from rigtool.spool import SAMPLES_PER_CHUNK
from rigtool.store import schema
from rigtool.store.codec import SAMPLE_COLUMNS, checked_columns, decode, decode_blocks, sample_names
from rigtool.store.reader import Reader
from rigtool.store.records import INT_POINT_COLUMNS, POINT_COLUMNS, TEXT_POINT_COLUMNS, RunRecord

READ_SAMPLES = SAMPLES_PER_CHUNK  # samples per chunk `iter_samples` yields (13 columns: ~7 MB)


_POINT_NAMES = tuple(dict.fromkeys(POINT_COLUMNS.values()))  # the steps columns `points` reads


def _point_columns(rows: list[dict]) -> dict[str, np.ndarray]:
    """Checked point rows as columns under POINT_COLUMNS' public names."""
    out = {}
    for name, column in POINT_COLUMNS.items():
        values = [r[column] for r in rows]
        if name in TEXT_POINT_COLUMNS:
            out[name] = np.array(values, dtype=str)
        elif name in INT_POINT_COLUMNS:
            out[name] = np.array(values, dtype=np.int64)
        else:
            out[name] = np.array([np.nan if v is None else v for v in values], dtype=float)
    return out


def _opt_float(value: object) -> float | None:
    return None if value is None else float(value)  # type: ignore[arg-type]


class RunQueries:
    """Checked reads of the runs in one database, on the open connection `conn`."""

    conn: sqlite3.Connection
    path: Path

    @property
    def version(self) -> int:
        """The database's schema version."""
        return schema.version(self.conn)

    @contextlib.contextmanager
    def snapshot(self) -> Iterator[None]:
        """Read in one transaction: every query inside sees the database as it was at the
        first, even while a sweep appends points. Nested use joins the outer snapshot; the
        outermost ends the transaction when it exits, also on an exception."""
        if self.conn.in_transaction:
            yield
            return
        self.conn.execute("BEGIN")
        try:
            yield
        finally:
            self._end_read()

    def _end_read(self) -> None:
        """End a snapshot's read transaction (nothing to end once the store is closed)."""
        with contextlib.suppress(sqlite3.ProgrammingError):
            if self.conn.in_transaction:
                self.conn.execute("COMMIT")

    @property
    def in_snapshot(self) -> bool:
        """Whether a snapshot (or any transaction) is open on this store's connection."""
        return self.conn.in_transaction

    @property
    def _read(self) -> Reader:
        """Checked reads from this store's connection."""
        return Reader(self.conn, f"run database {self.path}")

    def resolve_run_id(self, ref: str) -> str:
        """Accept a full id, an unambiguous literal id prefix, or `last`: the run most
        recently started or resumed. An empty or blank reference matches nothing."""
        if not ref.strip():
            raise UsageError(f"empty run id {ref!r}: give a run id, a prefix of one, or `last`")
        self._read.find_bad(None, "runs", ("id", "started_utc"), "1", ())
        if ref == "last":
            row = self.conn.execute(
                "SELECT id FROM runs ORDER BY started_utc DESC, id DESC LIMIT 1").fetchone()
            if row is None:
                raise UsageError(f"no runs in {self.path} yet: run `rigtool sweep` first")
            return self._run_id(row[0])
        rows = self.conn.execute(
            "SELECT id FROM runs WHERE substr(id, 1, ?) = ? ORDER BY id", (len(ref), ref)
        ).fetchall()
        if not rows:
            raise UsageError(f"no run {ref!r} in {self.path} (see `rigtool runs`)")
        ids = [self._run_id(r[0]) for r in rows[:5]]
        if len(rows) > 1:
            raise UsageError(f"run id prefix {ref!r} is ambiguous: {', '.join(ids)}")
        return ids[0]

    def _run_id(self, value: object) -> str:
        """A run id read from the runs table, checked to be text."""
        try:
            return RUN_COLUMNS["id"].check(value)
        except Invalid as exc:
            raise self._read.damaged(value, "runs.id", str(exc)) from None

    def run(self, run_id: str) -> dict:
        """The stored run: its columns, with protocol, rig, plan, metadata and actuator parsed
        from JSON and checked (DataError names the run and the field)."""
        rows = list(self._read.rows(run_id, "runs", tuple(RUN_COLUMNS), "id = ?", (run_id,)))
        if not rows:
            raise UsageError(f"no run {run_id!r} in {self.path}")
        out = rows[0]
        for key in ("protocol_json", "rig_json", "plan_json", "metadata_json", "actuator_json"):
            out[key.removesuffix("_json")] = out.pop(key)
        return out

    def run_record(self, run_id: str) -> RunRecord:
        """The typed record of a stored run."""
        from rigtool.units import NEUTRAL_BY_UNIT

        run = self.run(run_id)
        protocol = run.get("protocol") or {}
        command = protocol.get("command") or {}
        meta = {**(protocol.get("metadata") or {}), **(run.get("metadata") or {})}
        actuator = run.get("actuator") or {}
        unit = run.get("command_unit") or command.get("unit") or "percent"
        neutral = next((v for v in (actuator.get("neutral"), command.get("neutral"))
                        if v is not None), NEUTRAL_BY_UNIT.get(unit, 0.0))
        return RunRecord(
            id=run_id, name=run["name"], status=run["status"], created_utc=run["created_utc"],
            finished_utc=run.get("finished_utc"), stop_reason=run.get("stop_reason"),
            tool_version=run["tool_version"], seed=run.get("seed"), n_planned=run["n_planned"],
            command_unit=unit, neutral=float(neutral),
            command_min=_opt_float(actuator.get("command_min")),
            command_max=_opt_float(actuator.get("command_max")),
            thruster_id=None if meta.get("thruster_id") is None else str(meta["thruster_id"]),
            propeller_diameter_m=_opt_float(meta.get("propeller_diameter_m")),
            water_density_kg_m3=_opt_float(meta.get("water_density_kg_m3")),
            rig_name=(run.get("rig") or {}).get("name"), metadata=run.get("metadata") or {},
            protocol=protocol, rig=run.get("rig") or {})

    def points(self, run_id: str) -> dict[str, np.ndarray]:
        """A run's stored points as columns under POINT_COLUMNS' public names, in plan order."""
        return _point_columns(self._step_rows(run_id, _POINT_NAMES))

    def points_since(self, run_id: str, after_row: int | None
                     ) -> tuple[dict[str, np.ndarray], int | None]:
        """The run's points stored after steps row `after_row` (None: all of them), as `points`
        gives them, and the last row id read (`after_row` when nothing is new). Point rows are
        only ever appended, so a reader that keeps what it read fetches only what is new."""
        rows = self._step_rows(run_id, (*_POINT_NAMES, "id"), after_row=after_row)
        return _point_columns(rows), max((r["id"] for r in rows), default=after_row)

    def _step_rows(self, run_id: str, names: Sequence[str], where: str = "",
                   parse: bool = False, after_row: int | None = None) -> list[dict]:
        """Checked rows of a run's points in plan order (JSON parsed only if `parse`), those
        after steps row `after_row` if given; the cap counts all of the run's points."""
        self._read.count(run_id, "steps", "run_id = ?", (run_id,), MAX_STORED_POINTS)
        if after_row is None:
            key, args = "run_id = ?", (run_id,)
        else:  # `+run_id`: SQLite walks the rowid range, not the whole run in its index
            key, args = "+run_id = ? AND id > ?", (run_id, after_row)
        return list(self._read.rows(run_id, "steps", names, key + where, args, "ORDER BY idx",
                                    parse=parse))

    def sample_arrays(self, run_id: str, columns: Iterable[str] | None = None,
                      steps: Iterable[int] | None = None) -> dict[str, np.ndarray]:
        """Samples of a run (or of the points whose plan index is in `steps`) as columns:
        `step_idx` (the plan index) and `seq` as int64 (MISSING_INT where unrecorded), every
        other column float64 with NaN for NULL; in acquisition order."""
        chunks = list(self.iter_samples(run_id, columns, steps))
        if not chunks:
            return decode_blocks([], sample_names(columns), self.path)
        return {c: np.concatenate([ch[c] for ch in chunks]) for c in chunks[0]}

    def iter_samples(self, run_id: str, columns: Iterable[str] | None = None,
                     steps: Iterable[int] | None = None, batch: int = READ_SAMPLES
                     ) -> Iterator[dict[str, np.ndarray]]:
        """`sample_arrays` in chunks of about `batch` samples (stored blocks never split, so
        a chunk holds at most batch + SAMPLES_PER_CHUNK), for exports of any size."""
        cols = sample_names(columns)
        self._read.check_blocks(run_id, "st.run_id = ?", (run_id,))
        sql = (f"SELECT st.idx, b.n{''.join(', b.' + c for c in cols[1:])} FROM sample_blocks b "
               "JOIN steps st ON st.id = b.step_id WHERE st.run_id = ?")
        args: list[Any] = [run_id]
        if steps is not None:
            wanted = sorted({int(i) for i in steps})
            sql += f" AND st.idx IN ({', '.join('?' * len(wanted))})"
            args += wanted
        pending: list[tuple] = []
        held = 0
        for row in self.conn.execute(sql + " ORDER BY st.idx, b.chunk", args):
            pending.append(row)
            held += row[1]
            if held >= batch:
                yield decode_blocks(pending, cols, self.path)
                pending, held = [], 0
        if pending:
            yield decode_blocks(pending, cols, self.path)

    def sample_count(self, run_id: str) -> int:
        """How many samples the run's points hold in all (blocks checked first)."""
        self._read.check_blocks(run_id, "st.run_id = ?", (run_id,))
        return int(self.conn.execute(
            "SELECT COALESCE(SUM(b.n), 0) FROM sample_blocks b JOIN steps st "
            "ON st.id = b.step_id WHERE st.run_id = ?", (run_id,)).fetchone()[0])

    def point_sample_counts(self, run_id: str) -> dict[int, int]:
        """How many samples each point of the run holds, by plan index (blocks checked
        first); points without samples are left out."""
        self._read.check_blocks(run_id, "st.run_id = ?", (run_id,))
        return {int(i): int(n) for i, n in self.conn.execute(
            "SELECT st.idx, SUM(b.n) FROM sample_blocks b JOIN steps st ON st.id = b.step_id "
            "WHERE st.run_id = ? GROUP BY st.idx", (run_id,))}

    def iter_point_samples(self, run_id: str, columns: Iterable[str], batch: int = READ_SAMPLES,
                           idx_range: tuple[int, int] | None = None
                           ) -> Iterator[dict[str, np.ndarray]]:
        """A run's samples in plan order (of the points whose plan index lies in `idx_range`,
        both ends included, when given), in chunks of whole points of at most about `batch`
        samples (a point longer than that is a chunk of its own): `step_idx` then `columns`,
        as `sample_arrays` gives them. A chunk ends before a point when one more point as
        long as the last would pass `batch`. Memory is bounded by the chunk, not the run."""
        cols = sample_names(columns)
        self._read.check_blocks(run_id, "st.run_id = ?", (run_id,))
        where, args = "st.run_id = ?", [run_id]
        if idx_range is not None:
            where += " AND st.idx BETWEEN ? AND ?"
            args += [int(idx_range[0]), int(idx_range[1])]
        sql = (f"SELECT st.idx, b.n{''.join(', b.' + c for c in cols[1:])} FROM sample_blocks b "
               f"JOIN steps st ON st.id = b.step_id WHERE {where} ORDER BY st.idx, b.chunk")
        pending: list[tuple] = []
        held = point = 0
        for row in self.conn.execute(sql, args):
            if pending and row[0] != pending[-1][0]:
                if held + point > batch:
                    yield decode_blocks(pending, cols, self.path)
                    pending, held = [], 0
                point = 0
            pending.append(row)
            held += row[1]
            point += row[1]
        if pending:
            yield decode_blocks(pending, cols, self.path)

    def run_ids(self) -> list[str]:
        """Every run id, oldest first."""
        self._read.find_bad(None, "runs", ("id",), "1", ())
        return [self._run_id(r[0]) for r in self.conn.execute("SELECT id FROM runs ORDER BY id")]

    def runs(self, limit: int = 50) -> list[dict]:
        """The newest `limit` runs: id, name, status, created_utc, n_planned, command_unit,
        n_steps (stored points) and calibrated_utc (the newest calibration's time, None when
        never calibrated), each value checked."""
        names = ("id", "name", "status", "created_utc", "n_planned", "command_unit")
        self._read.find_bad(None, "runs", names, "1", ())
        self._read.find_bad(None, "calibrations", ("created_utc",), "1", ())
        return self._read.listing(
            f"SELECT {', '.join('r.' + n for n in names)}, "
            "(SELECT count(*) FROM steps s WHERE s.run_id = r.id) AS n_steps, "
            "(SELECT max(c.created_utc) FROM calibrations c WHERE c.run_id = r.id) "
            "AS calibrated_utc FROM runs r ORDER BY r.id DESC LIMIT ?", [limit])

    def run_fingerprints(self) -> list[dict]:
        """Per run, oldest first, what tells whether it changed since an export: status, end
        and stop reason; points (count, last index, samples); calibrations (count, newest);
        events (count). Content only, no row ids, so two databases' copies of a run agree."""
        self._read.find_bad(None, "runs", ("id", "status", "finished_utc", "stop_reason"), "1",
                            ())
        self._read.find_bad(None, "steps", ("idx", "n"), "1", ())
        self._read.find_bad(None, "calibrations", ("created_utc",), "1", ())
        return self._read.listing(
            "SELECT r.id AS run_id, r.status, r.finished_utc, r.stop_reason, "
            "coalesce(s.points, 0) AS points, s.last_idx, coalesce(s.samples, 0) AS samples, "
            "coalesce(c.calibrations, 0) AS calibrations, c.calibrated_utc, "
            "coalesce(e.events, 0) AS events FROM runs r "
            "LEFT JOIN (SELECT run_id, count(*) AS points, max(idx) AS last_idx, "
            "sum(n) AS samples FROM steps GROUP BY run_id) s ON s.run_id = r.id "
            "LEFT JOIN (SELECT run_id, count(*) AS calibrations, max(created_utc) AS "
            "calibrated_utc FROM calibrations GROUP BY run_id) c ON c.run_id = r.id "
            "LEFT JOIN (SELECT run_id, count(*) AS events FROM events GROUP BY run_id) e "
            "ON e.run_id = r.id ORDER BY r.id", [])

    def steps(self, run_id: str) -> list[dict]:
        """A run's stored points, every column checked (counters_json as stored text)."""
        return self._step_rows(run_id, tuple(STEP_COLUMNS))

    def events(self, run_id: str, kind: str | None = None) -> list[dict]:
        """A run's events (of `kind`), oldest first, each `detail` parsed and checked."""
        where, args = "run_id = ?", [run_id]
        if kind:
            where += " AND kind = ?"
            args.append(kind)
        self._read.count(run_id, "events", where, args, MAX_STORED_EVENTS, "detail_json",
                         MAX_EVENT_BYTES)
        rows = list(self._read.rows(run_id, "events", tuple(EVENT_COLUMNS), where, args,
                                    "ORDER BY id"))
        for r in rows:
            r["detail"] = self._read.detail(run_id, r, r.pop("detail_json"))
        return rows

    def transport_counters(self, run_id: str, after_row: int | None = None) -> dict:
        """Transport counters summed over a run's stored points (those after steps row
        `after_row`, as `points_since`), and the points with problems.

        Returns {"totals": {role: {counter: n}}, "problem_points": [idx, ...]}, where a
        problem is any counter outside TRAFFIC_COUNTERS that moved during the point.
        """
        totals: dict[str, dict[str, int]] = {}
        problems = []
        rows = self._step_rows(run_id, ("idx", "counters_json"), " AND counters_json IS NOT NULL",
                               parse=True, after_row=after_row)
        for row in rows:
            bad = False
            for role, counters in row["counters_json"].items():
                into = totals.setdefault(role, {})
                for name, n in counters.items():
                    into[name] = into.get(name, 0) + n
                    bad = bad or (n > 0 and name not in TRAFFIC_COUNTERS)
            if bad:
                problems.append(row["idx"])
        return {"totals": totals, "problem_points": problems}

    def latest_calibration(self, run_id: str) -> dict | None:
        """The run's most recent calibration record (with its `state` blob, None for one
        stored before schema v6), or None when it was never calibrated."""
        names = ("id", "created_utc", "tool_version", "out_dir", "summary_json", "state")
        self._read.count(run_id, "calibrations", "run_id = ?", (run_id,),
                         MAX_STORED_CALIBRATIONS)
        rows = list(self._read.rows(run_id, "calibrations", names, "run_id = ?", (run_id,),
                                    "ORDER BY id DESC LIMIT 1"))
        if not rows:
            return None
        out = rows[0]
        out["summary"] = out.pop("summary_json")
        return out

    def check_run(self, run_id: str) -> None:
        """Check everything stored for a run, keeping nothing: DataError on the first bad value."""
        with self.snapshot():
            self.run(run_id)
            self._step_rows(run_id, tuple(STEP_COLUMNS))
            self.events(run_id)
            self.latest_calibration(run_id)
            self._read.check_blocks(run_id, "st.run_id = ?", (run_id,))

    def step_samples(self, step_id: int, columns: Iterable[str] = ("t_s", "thrust_n")
                     ) -> dict[str, np.ndarray]:
        """The samples of one stored point as float arrays (missing -> NaN), in time order."""
        cols = checked_columns(columns)
        self._read.check_blocks(None, "b.step_id = ?", (step_id,))
        blocks = self.conn.execute(f"SELECT n, {', '.join(cols)} FROM sample_blocks WHERE "
                                   "step_id = ? ORDER BY chunk", (step_id,)).fetchall()
        return self._decoded(blocks, cols) if blocks else {c: np.empty(0) for c in cols}

    def iter_step_samples(self, step_id: int, columns: Iterable[str], batch: int = READ_SAMPLES
                          ) -> Iterator[dict[str, np.ndarray]]:
        """`step_samples` in chunks of whole stored blocks, each chunk ending once it holds
        `batch` samples or more, so a point of any length is read in bounded memory."""
        cols = checked_columns(columns)
        self._read.check_blocks(None, "b.step_id = ?", (step_id,))
        pending: list[tuple] = []
        held = 0
        for row in self.conn.execute(f"SELECT n, {', '.join(cols)} FROM sample_blocks WHERE "
                                     "step_id = ? ORDER BY chunk", (step_id,)):
            pending.append(row)
            held += row[0]
            if held >= batch:
                yield self._decoded(pending, cols)
                pending, held = [], 0
        if pending:
            yield self._decoded(pending, cols)

    def _decoded(self, blocks: list[tuple], cols: list[str]) -> dict[str, np.ndarray]:
        return {c: np.concatenate([decode(b[i], b[0], c, self.path) for b in blocks])
                for i, c in enumerate(cols, start=1)}

    def samples(self, run_id: str, columns: Iterable[str] = SAMPLE_COLUMNS) -> dict[str, np.ndarray]:
        """All samples of a run as float arrays (missing -> NaN), in plan order, each point's
        in acquisition order; one snapshot, so a sweep appending points is not half seen.
        Every block's count and sizes are checked before the arrays are allocated."""
        cols = checked_columns(columns)
        names = ["st.id" if c == "step_id" else "b." + c for c in cols]
        join = "FROM sample_blocks b JOIN steps st ON st.id = b.step_id WHERE st.run_id = ?"
        with self.snapshot():
            self._read.check_blocks(run_id, "st.run_id = ?", (run_id,))
            n = self.conn.execute(f"SELECT COALESCE(SUM(b.n), 0) {join}", (run_id,)).fetchone()[0]
            out = {c: np.empty(n) for c in cols}  # filled in place: 8 bytes per value, no copies
            cur = self.conn.execute(f"SELECT b.n, {', '.join(names)} {join} "
                                    "ORDER BY st.idx, b.chunk", (run_id,))
            filled = 0
            for row in cur:
                size = row[0]
                for i, c in enumerate(cols, start=1):
                    out[c][filled:filled + size] = (row[i] if c == "step_id"
                                                    else decode(row[i], size, c, self.path))
                filled += size
        return out

