"""One read-only snapshot of a run -> the JSON-ready dict the watch page draws.

Everything is read through `rigtool.open()` (a `mode=ro` connection) inside one
`lab.snapshot()`, so the points, the trace, the events and the run status agree. The work
per refresh is bounded: at most MAX_POINTS points, a trace of at most MAX_TRACE samples
(min/max per bucket, streamed), the last MAX_EVENTS events, each detail cut to MAX_DETAIL
characters. A stored point never changes, so its decimated trace is computed once.
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

import rigtool.api
from rigtool.counters import TRAFFIC_COUNTERS
from rigtool.errors import RigtoolError
from rigtool.store import owner_gone
from rigtool.watch.rows import RunRows

MAX_POINTS = 5000  # points sent per refresh (the newest)
MAX_TRACE = 2000  # samples of the current point's trace sent per refresh
MAX_EVENTS = 200  # newest events sent per refresh
READ_SHARE = 10.0  # the next read waits 10 times the last one: reading takes <= 10 % of a core
MAX_DETAIL = 400  # characters of one event's detail
MAX_GROUPS = 12  # depth/voltage groups plotted separately; the rest share one
MIN_FIT_POINTS = 3  # stored points per direction before a provisional C_p is shown
TRACE_COLUMNS = ("t_s", "thrust_n", "speed_rpm", "current_a")
ENDED = ("completed", "aborted", "failed", "interrupted")
TRIPS = ("limit_trip", "device_fault", "neutral_failed", "supply_unsafe")
RUN_RECHECK_S = 5.0  # a run missing from the newest runs listing: full record this often


def _num(value: Any) -> float | None:
    """A JSON-safe float: None for NaN, inf or None."""
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def _nums(values: np.ndarray) -> list[float | None]:
    """An array as a JSON-safe list (NaN and inf as null)."""
    arr = np.asarray(values, dtype=float)
    return [float(v) if math.isfinite(v) else None for v in arr.tolist()]


def decimate(chunks: Any, n_total: int, buckets: int = MAX_TRACE // 2) -> dict[str, np.ndarray]:
    """Min/max of thrust per bucket of samples, streamed chunk by chunk: two samples per
    bucket (at the thrust minimum and maximum, in time order, other columns taken there),
    so at most 2 * `buckets` samples whatever `n_total`. Short traces come back whole."""
    if n_total <= 2 * buckets:
        parts = list(chunks)
        if not parts:
            return {c: np.empty(0) for c in TRACE_COLUMNS}
        return {c: np.concatenate([p[c] for p in parts]) for c in TRACE_COLUMNS}
    found: list[dict[str, np.ndarray]] = []
    offset = 0
    for chunk in chunks:
        n = len(chunk["t_s"])
        bucket = (np.arange(offset, offset + n) * buckets) // n_total
        keep = _extremes(bucket, chunk["thrust_n"])
        found.append({"bucket": bucket[keep], **{c: chunk[c][keep] for c in TRACE_COLUMNS}})
        offset += n
    if not found:
        return {c: np.empty(0) for c in TRACE_COLUMNS}
    rows = {c: np.concatenate([f[c] for f in found]) for c in ("bucket", *TRACE_COLUMNS)}
    keep = _extremes(rows["bucket"], rows["thrust_n"])  # buckets split between chunks
    order = np.argsort(rows["t_s"][keep], kind="stable")
    return {c: rows[c][keep][order] for c in TRACE_COLUMNS}


def _extremes(bucket: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Sorted indices of the minimum and maximum finite value of each run of equal
    (non-decreasing) bucket ids; buckets without a finite value give none."""
    if not len(bucket):
        return np.empty(0, dtype=np.int64)
    starts = np.flatnonzero(np.r_[True, bucket[1:] != bucket[:-1]])
    finite = np.isfinite(values)
    lo = np.minimum.reduceat(np.where(finite, values, np.inf), starts)
    hi = np.maximum.reduceat(np.where(finite, values, -np.inf), starts)
    seg = np.repeat(np.arange(len(starts)), np.diff(np.r_[starts, len(bucket)]))
    out = []
    for target in (lo, hi):
        hit = np.flatnonzero(finite & (values == target[seg]))
        out.append(hit[np.r_[True, seg[hit][1:] != seg[hit][:-1]]] if len(hit) else hit)
    return np.unique(np.concatenate(out))


def fit_cp(speed: np.ndarray, thrust: np.ndarray) -> dict[str, Any]:
    """Provisional f = C_p |n| n per direction, least squares through the origin on the
    points' mean speed (r/min) and mean thrust (N)."""
    out: dict[str, Any] = {}
    ok = np.isfinite(speed) & np.isfinite(thrust)
    if not ok.any():
        return {"fwd": None, "rev": None, "reason": "no speed recorded: C_p needs speed feedback"}
    top = float(np.max(np.abs(speed[ok])))
    for key, sign in (("fwd", 1.0), ("rev", -1.0)):
        sel = ok & (sign * speed > 0.05 * top)
        if sel.sum() < MIN_FIT_POINTS:
            out[key] = {"n": int(sel.sum()), "C_p": None}
            continue
        x = np.abs(speed[sel]) * speed[sel]
        f = thrust[sel]
        c = float(np.dot(x, f) / np.dot(x, x))
        ss = float(np.sum((f - f.mean()) ** 2))
        r2 = 1.0 - float(np.sum((f - c * x) ** 2)) / ss if ss > 0 else None
        out[key] = {"n": int(sel.sum()), "C_p": _num(c), "r2": _num(r2)}
    return out


class Watcher:
    """Reads one run (or the latest run, `follow`) from a run database, read-only, and
    builds the page's data; every read goes through one thread of its own, because an
    SQLite connection belongs to the thread that opened it."""

    def __init__(self, db: str | Path, run: str | None = None, *, follow: bool = False,
                 cache_s: float = 0.5, clock: Callable[[], float] = time.monotonic) -> None:
        """`run`: a run reference resolved once; `follow`: the latest run at each refresh."""
        self.db = Path(db)
        self.ref = run or "last"
        self.follow = follow
        self.cache_s = cache_s
        self.clock = clock
        self._lab: rigtool.api.Lab | None = None
        self._run_id: str | None = None
        self._pinned = False  # following: the running run found is kept
        self._read_s = 0.0  # how long the last read took
        self._lock = threading.Lock()
        self._cached: tuple[float, dict] | None = None
        self._records: dict[str, dict] = {}
        self._trace: tuple[tuple[str, int], dict] | None = None
        self._seen: dict[str, tuple[int, float]] = {}  # run -> (points, wall time first seen)
        self._rate: dict[str, tuple[int, float]] = {}  # run -> first (points, time) observed
        self._listed_at: dict[str, float] = {}
        self._rows = RunRows()  # points and counters, read incrementally
        self._reader = ThreadPoolExecutor(1, thread_name_prefix="rigtool-watch-reader")

    def resolve(self) -> str | None:
        """The run to show (None while a followed database has no run yet). Following, the
        latest run is shown until one is running: that one is then kept (another run created
        in the same database meanwhile does not take the page over)."""
        lab = self._open()
        if self._run_id is not None and (not self.follow or self._pinned):
            return self._run_id
        try:
            self._run_id = lab.store.resolve_run_id(self.ref)
        except RigtoolError:
            if not self.follow:
                raise
            return None
        if self.follow and lab.store.run(self._run_id).get("status") == "running":
            self._pinned = True
        return self._run_id

    def _open(self) -> rigtool.api.Lab:
        if self._lab is None:
            self._lab = rigtool.api.open(self.db)
        return self._lab

    def close(self) -> None:
        """Close the read-only connection and its reader thread."""
        self._reader.submit(self._close).result()
        self._reader.shutdown()

    def _close(self) -> None:
        if self._lab is not None:
            self._lab.close()
            self._lab = None
            self._rows = RunRows()

    def start(self) -> str | None:
        """Open the database and resolve the run now (errors surface before serving)."""
        return self._reader.submit(self.resolve).result()

    def data(self) -> dict:
        """The page's data: one snapshot, at most one read per `cache_s` for all clients."""
        return self._reader.submit(self._data).result()

    def _data(self) -> dict:
        with self._lock:
            now = self.clock()
            wait = max(self.cache_s, READ_SHARE * self._read_s)
            if self._cached is not None and (now - self._cached[0] < wait
                                             or self._final(self._cached[1])):
                return self._cached[1]
            lab = self._open()
            started = time.monotonic()
            with lab.snapshot():
                run_id = self.resolve()
                doc = self._build(lab, run_id, now)
            self._read_s = time.monotonic() - started
            self._cached = (self.clock(), doc)  # stamped when read: queued requests share it
            return doc

    def _final(self, doc: dict) -> bool:
        """Whether a document can no longer change: its run has ended and is the one shown
        for good (not following, or pinned)."""
        run = doc.get("run") or {}
        return bool(run.get("ended")) and (not self.follow or self._pinned)

    def _build(self, lab: rigtool.api.Lab, run_id: str | None, now: float) -> dict:
        bounds = {"max_points": MAX_POINTS, "max_trace": MAX_TRACE, "max_events": MAX_EVENTS}
        if run_id is None:
            return {"run": None, "waiting": f"no run in {self.db.name} yet", "bounds": bounds,
                    "database": self.db.name}
        store = lab.store
        record = self._record(store, run_id, now)
        points = self._rows.points(store, run_id)
        events = store.events(run_id)
        counters = self._rows.counters(store, run_id)
        stored = len(points["step_idx"])
        current = self._current(record, points)
        return {
            "run": {k: record.get(k) for k in ("id", "name", "status", "stop_reason",
                                               "created_utc", "finished_utc", "command_unit",
                                               "n_planned")}
                   | {"ended": record["status"] in ENDED, "rig": record["rig_name"]},
            "database": self.db.name,
            "progress": self._progress(record, points, current, now),
            "points": self._points(points),
            "trace": self._trace_of(store, run_id, points),
            "events": self._events(events),
            "counters": self._counters(counters, stored),
            "fit": {"provisional": True, "unit": "N/(r/min)^2",
                    "label": "provisional: least squares on the stored points' mean thrust "
                             "and speed, not a calibration",
                    **fit_cp(points["speed_all_mean_rpm"], points["thrust_all_mean_n"])},
            "bounds": bounds,
        }

    def _record(self, store: Any, run_id: str, now: float) -> dict:
        """The run record: its plan and timing parsed once per run, its status every refresh;
        a run still marked running whose sweep process on this host is gone is shown as
        interrupted (the store is not written: the next rigtool command marks it)."""
        rec = self._stored_record(store, run_id, now)
        if rec["status"] == "running" and owner_gone(rec["host"], rec["pid"]):
            return rec | {"status": "interrupted",
                          "stop_reason": "its sweep process is gone (killed or crashed)"}
        return rec

    def _stored_record(self, store: Any, run_id: str, now: float) -> dict:
        """The run record as stored."""
        rec = self._records.get(run_id)
        listed = {r["id"]: r for r in store.runs(limit=20)}.get(run_id)
        stale = listed is None and now - self._listed_at.get(run_id, -1e9) > RUN_RECHECK_S
        if rec is None or stale or (listed and listed["status"] != rec["status"]):
            run = store.run(run_id)
            timing = (run.get("protocol") or {}).get("timing") or {}
            rec = {k: run.get(k) for k in ("id", "name", "status", "stop_reason",
                                           "created_utc", "finished_utc", "command_unit",
                                           "n_planned")}
            rec["rig_name"] = (run.get("rig") or {}).get("name")
            rec["host"], rec["pid"] = run.get("host"), run.get("pid")
            rec["plan"] = [s for s in run.get("plan") or [] if isinstance(s, dict)]
            rec["timing"] = _timing(timing)
            self._records = {run_id: rec}
            self._listed_at[run_id] = now
        return rec

    def _current(self, record: dict, points: dict) -> dict | None:
        """The plan step the sweep works on: the first not stored (None when all are)."""
        done = set(points["step_idx"].tolist())
        for step in record["plan"]:
            if step.get("idx") not in done:
                return {k: step.get(k) for k in ("idx", "command", "depth_m", "voltage_v",
                                                 "repeat", "direction")}
        return None

    def _progress(self, record: dict, points: dict, current: dict | None, now: float) -> dict:
        run_id, done = record["id"], len(points["step_idx"])
        planned = int(record["n_planned"] or 0)
        seen = self._seen.get(run_id)
        if seen is None or seen[0] != done:
            seen = self._seen[run_id] = (done, now)
        first = self._rate.setdefault(run_id, (done, now))
        eta, basis = None, None
        if record["status"] == "running" and planned > done:
            if done > first[0] and now > first[1]:
                eta = (planned - done) * (now - first[1]) / (done - first[0])
                basis = "points stored while watching"
            elif done >= 2:
                t = points["t_end_s"]
                per = (float(np.nanmax(t)) - float(np.nanmin(points["t_start_s"]))) / done
                eta, basis = (planned - done) * per, "run time of the stored points"
        state = record["status"] if record["status"] in ENDED else "running"
        if state == "running":
            state = _phase(record["timing"], now - seen[1]) if current else "finishing"
        return {"done": done, "planned": planned, "eta_s": _num(eta), "eta_basis": basis,
                "current": current, "state": state,
                "state_note": "estimated from the protocol's timing and the time since the "
                              "last stored point"}

    def _points(self, points: dict) -> dict:
        n = len(points["step_idx"])
        keep = slice(max(0, n - MAX_POINTS), n)
        depth, volt = points["depth_m"][keep], points["voltage_set_v"][keep]
        labels: dict[tuple, int] = {}
        group = []
        for d, v in zip(depth.tolist(), volt.tolist(), strict=True):
            key = (None if not math.isfinite(d) else d, None if not math.isfinite(v) else v)
            if key not in labels:
                labels[key] = min(len(labels), MAX_GROUPS)
            group.append(labels[key])
        names = [""] * (min(len(labels), MAX_GROUPS) + (len(labels) > MAX_GROUPS))
        for (d, v), i in labels.items():
            names[i] = "other" if i == MAX_GROUPS else (
                ("depth ?" if d is None else f"{d:g} m") + ("" if v is None else f", {v:g} V"))
        return {"n_stored": n, "n_sent": len(group), "truncated": n > MAX_POINTS,
                "step_idx": points["step_idx"][keep].tolist(),
                "command": _nums(points["command"][keep]),
                "thrust": _nums(points["thrust_all_mean_n"][keep]),
                "group": group, "groups": names,
                "current_pass": _current_pass(points, keep)}

    def _trace_of(self, store: Any, run_id: str, points: dict) -> dict | None:
        """The latest stored point's samples, decimated once and kept (a point never changes)."""
        if not len(points["step_idx"]):
            return None
        last = int(np.argmax(points["step_idx"]))
        idx, n = int(points["step_idx"][last]), int(points["n_samples"][last])
        key = (run_id, idx)
        if self._trace is None or self._trace[0] != key:
            chunks = store.iter_samples(run_id, TRACE_COLUMNS, [idx])
            cols = decimate(chunks, n)
            self._trace = (key, {
                "step_idx": idx, "command": _num(points["command"][last]),
                "depth_m": _num(points["depth_m"][last]), "n_samples": n,
                "n_sent": len(cols["t_s"]),
                **{c: (_nums(cols[c]) if np.isfinite(cols[c]).any() or c in ("t_s", "thrust_n")
                       else None) for c in TRACE_COLUMNS}})
        return self._trace[1]

    @staticmethod
    def _events(events: list[dict]) -> dict:
        items = []
        for e in events[-MAX_EVENTS:]:
            detail = detail_text(e["detail"])
            items.append({"t_s": _num(e["t_s"]), "kind": str(e["kind"]),
                          "step_idx": e["step_idx"], "trip": e["kind"] in TRIPS,
                          "detail": detail[:MAX_DETAIL] + ("…" if len(detail) > MAX_DETAIL else "")})
        return {"n_total": len(events), "items": items,
                "trips": sum(1 for e in events if e["kind"] in TRIPS)}

    @staticmethod
    def _counters(summary: dict, stored: int) -> dict:
        roles = {}
        for role, counters in summary["totals"].items():
            roles[str(role)] = [{"name": str(k), "n": int(v), "problem": k not in TRAFFIC_COUNTERS
                                 and v > 0} for k, v in counters.items()]
        return {"roles": roles, "problem_points": len(summary["problem_points"]),
                "points": stored}


def detail_text(detail: Any, nested: bool = False) -> str:
    """An event's detail as a person reads it: `key value` pairs joined by `; ` (a nested
    object in braces), lists in brackets, numbers to 4 significant digits (not JSON with
    17-digit floats)."""
    if isinstance(detail, dict):
        pairs = "; ".join(f"{k} {detail_text(v, True)}" for k, v in detail.items())
        return "{" + pairs + "}" if nested else pairs
    if isinstance(detail, (list, tuple)):
        return "[" + ", ".join(detail_text(v, True) for v in detail) + "]"
    if isinstance(detail, bool) or detail is None:
        return json.dumps(detail)
    if isinstance(detail, float):
        return f"{detail:.4g}"
    return str(detail)


def _timing(timing: dict) -> dict:
    """Seconds of settle (its maximum), acquisition and rest per point, from the protocol."""
    settle = timing.get("settle") or {}
    if settle.get("seconds") is not None:
        settle_s = float(settle["seconds"])
    else:
        steady = settle.get("until_steady") or {}
        settle_s = float(steady.get("min_s") or 0) + 2 * float(steady.get("window_s") or 0)
    acquire = timing.get("acquire") or {}
    rate = float(acquire.get("rate_hz") or 0) or 1.0
    acquire_s = acquire.get("seconds")
    if acquire_s is None:
        acquire_s = float(acquire.get("samples") or 0) / rate
    return {"settle_s": settle_s, "acquire_s": float(acquire_s),
            "rest_s": float(timing.get("rest_s") or 0)}


def _phase(timing: dict, since_s: float) -> str:
    """What the sweep is probably doing `since_s` after its last point was stored."""
    if since_s < timing["rest_s"]:
        return "rest"
    if since_s < timing["rest_s"] + timing["settle_s"]:
        return "settling"
    return "acquiring"


def _current_pass(points: dict, keep: slice) -> list[bool]:
    """Points of the newest pass: the last run of points sharing the newest point's depth,
    voltage, repeat and direction, in plan order."""
    keys = list(zip(points["depth_m"].tolist(), points["voltage_set_v"].tolist(),
                    points["repeat"].tolist(), points["direction"].tolist(), strict=True))
    flags = [False] * len(keys)
    i = len(keys) - 1
    while i >= 0 and _same(keys[i], keys[-1]):
        flags[i] = True
        i -= 1
    return flags[keep]


def _same(a: tuple, b: tuple) -> bool:
    """Equal pass keys, NaN equal to NaN."""
    return all(x == y or (isinstance(x, float) and isinstance(y, float)
                          and math.isnan(x) and math.isnan(y)) for x, y in zip(a, b, strict=True))
