"""A run's points and transport counters kept between the watch page's reads, so a refresh
fetches only the points stored since the last one (point rows are only ever appended) and
the work per refresh stays bounded however long the run grows."""

from __future__ import annotations

from typing import Any

import numpy as np


class RunRows:
    """The points (as `Store.points`) and transport counters (as `Store.transport_counters`)
    of one run, read incrementally; each read gives what a full read of both would."""

    def __init__(self) -> None:
        self._run_id: str | None = None
        self._last_row: int | None = None  # the last steps row read
        self._points: dict[str, np.ndarray] = {}
        self._counters: dict = {}
        self._next: tuple[dict[str, np.ndarray], int | None, str] | None = None

    def points(self, store: Any, run_id: str) -> dict[str, np.ndarray]:
        """The run's points; call `counters` next, in the same snapshot of `store`."""
        if run_id == self._run_id:
            new, last = store.points_since(run_id, self._last_row)
            held = self._points["step_idx"]
            if not len(new["step_idx"]):
                self._next = (self._points, last, "same")
                return self._points
            if not len(held) or int(new["step_idx"].min()) > int(held.max()):
                points = {k: np.concatenate([self._points[k], new[k]]) for k in new}
                self._next = (points, last, "add")
                return points
        points, last = store.points_since(run_id, None)  # new run, or a point before a kept one
        self._next = (points, last, "all")
        return points

    def counters(self, store: Any, run_id: str) -> dict:
        """The run's transport counters, as of the points `points` just read; what was read
        is kept only now, so a read that failed on the way is done again in full."""
        assert self._next is not None, "points() first"
        points, last, how = self._next
        self._next = None
        if how == "all":
            counters = store.transport_counters(run_id)
        elif how == "same":
            counters = self._counters
        else:
            added = store.transport_counters(run_id, self._last_row)
            totals = {role: dict(held) for role, held in self._counters["totals"].items()}
            for role, moved in added["totals"].items():
                into = totals.setdefault(role, {})
                for name, n in moved.items():
                    into[name] = into.get(name, 0) + n
            counters = {"totals": totals,
                        "problem_points": self._counters["problem_points"] + added["problem_points"]}
        self._run_id, self._points, self._last_row, self._counters = run_id, points, last, counters
        return counters
