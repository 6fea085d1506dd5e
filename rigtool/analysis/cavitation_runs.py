"""Which runs the quasi-cavitation stage uses, read from the store: whether a run qualifies
(shallow points, speed and current feedback), its deep base run, and the extra training runs.

Every store read of the stage's run-selection policy is here; the pipeline (cavitation.py)
takes the decision (`cavitation_stage`) and loads the runs it names.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from rigtool.analysis.results import DEEP_DEPTH_M
from rigtool.errors import UsageError
from rigtool.store import Store

# steps column, name
FEEDBACK_NEEDED = (("speed_all_mean_rpm", "speed"), ("current_all_mean_a", "current"))


def is_shallow(store: Store, run_id: str) -> bool:
    """True when any point of the run is shallower than the deep limit (0.6 m)."""
    return _any_shallow(store.steps(run_id))


def _any_shallow(steps: list[dict]) -> bool:
    return any(s["depth_m"] is not None and s["depth_m"] < DEEP_DEPTH_M for s in steps)


def _missing_feedback(steps: list[dict]) -> str | None:
    """The feedback (speed, current) no point has a finite sample of, as text; None if both do.

    A point's mean is NULL when none of its samples is finite.
    """
    missing = [label for key, label in FEEDBACK_NEEDED if all(s[key] is None for s in steps)]
    return " and ".join(missing) or None


def cavitation_applicable(store: Store, run_id: str) -> str | None:
    """Why the quasi-cavitation stage does not apply to a run, or None when it does.

    It needs shallow points and speed and current feedback (the BETM reads both); any other
    run is an ordinary calibration at its depth.
    """
    steps = store.steps(run_id)
    if not _any_shallow(steps):
        return f"run {run_id} has no point shallower than {DEEP_DEPTH_M:g} m"
    missing = _missing_feedback(steps)
    return f"run {run_id} has no {missing} feedback" if missing else None


def base_run_problem(store: Store, run_id: str) -> str | None:
    """What keeps a run from being a BETM base run (all points deep, speed and current
    feedback), or None when it can be one."""
    return _base_problem(run_id, store.steps(run_id))


def _base_problem(run_id: str, steps: list[dict]) -> str | None:
    if not steps:
        return f"run {run_id} has no recorded points"
    if any(s["depth_m"] is None or s["depth_m"] < DEEP_DEPTH_M for s in steps):
        return f"run {run_id} is not deep (a base run has every point at {DEEP_DEPTH_M:g} m or deeper)"
    missing = _missing_feedback(steps)
    return f"run {run_id} has no {missing} feedback" if missing else None


def _thruster_id(run: dict) -> str | None:
    """The thruster id of a stored run: its metadata, else its protocol's."""
    return (run.get("metadata") or {}).get("thruster_id") or \
        ((run.get("protocol") or {}).get("metadata") or {}).get("thruster_id")


def _other_thruster(store: Store, run_id: str, other_id: str) -> str | None:
    """Why run `other_id` cannot join `run_id`'s model: another thruster id (None when the
    ids agree, or either run has none)."""
    mine, theirs = _thruster_id(store.run(run_id)), _thruster_id(store.run(other_id))
    if mine and theirs and mine != theirs:
        return f"run {other_id} is thruster {theirs!r}, run {run_id} is thruster {mine!r}"
    return None


def unchecked_thruster(store: Store, run_id: str, other_id: str, role: str) -> str | None:
    """A warning when run `other_id` (the `role`) joins `run_id`'s model and either has no
    thruster id: nothing shows they are the same thruster."""
    mine, theirs = _thruster_id(store.run(run_id)), _thruster_id(store.run(other_id))
    if mine and theirs:
        return None
    return (f"{role} run {other_id} ({_id_text(theirs)}) joins the model of run {run_id} "
            f"({_id_text(mine)}): with an id missing, rigtool cannot check they are the same "
            "thruster (set metadata.thruster_id in both protocols)")


def _id_text(tid: str | None) -> str:
    return f"thruster {tid!r}" if tid else "no thruster id"


def _latest_base_run(store: Store, run_id: str) -> str | None:
    """Most recent completed base run of the same thruster with >= 10 commands, or None."""
    tid = _thruster_id(store.run(run_id))
    for row in store.runs(limit=10_000):
        if row["id"] == run_id or row["status"] != "completed":
            continue
        steps = store.steps(row["id"])
        if _base_problem(row["id"], steps) or len({s["command"] for s in steps}) < 10:
            continue
        if tid is None or _thruster_id(store.run(row["id"])) == tid:
            return row["id"]
    return None


def _no_base_run(run_id: str) -> str:
    return (f"no deep base run found for {run_id}: record a deep full-range run with speed "
            "and current feedback (e.g. protocols/luo2020-baseline.yaml) or pass --base RUN_ID")


def find_base_run(store: Store, run_id: str) -> str:
    """Most recent completed run of the same thruster, all points deep, with speed and current
    feedback and >= 10 commands."""
    base = _latest_base_run(store, run_id)
    if base is None:
        raise UsageError(_no_base_run(run_id))
    return base


@dataclass(frozen=True)
class CavitationStage:
    """Whether a run gets the quasi-cavitation stage: its base run, or why not."""

    base_run_id: str | None
    reason: str | None = None  # why there is no stage
    warn: bool = False  # the run qualifies but has no base run: worth a warning
    notes: tuple[str, ...] = ()  # about the base run (an id that cannot be checked)

    @property
    def warnings(self) -> list[str]:
        """The warnings `calibrate` and `report` both give: a qualifying run left without the
        stage, or a base run whose thruster cannot be checked."""
        lost = [f"no quasi-cavitation section: {self.reason}"] if self.warn else []
        return [*lost, *(f"quasi-cavitation: {n}" for n in self.notes)]


def cavitation_stage(store: Store, run_id: str, base_ref: str | None) -> CavitationStage:
    """Decide the quasi-cavitation stage of a run (the one decision calibrate and report share).

    A `base_ref` (--base) is checked: UsageError when the run does not qualify, or the base
    run is not a deep run with speed and current feedback, or is another thruster id's.
    """
    reason = cavitation_applicable(store, run_id)
    if reason is not None:
        if base_ref:
            raise UsageError(f"--base {base_ref}: no quasi-cavitation analysis applies: {reason}")
        return CavitationStage(None, reason)
    if base_ref:
        base_id = store.resolve_run_id(base_ref)
        problem = base_run_problem(store, base_id) or _other_thruster(store, run_id, base_id)
        if problem:
            raise UsageError(f"--base {base_ref}: not usable as a base run: {problem}")
    else:
        base_id = _latest_base_run(store, run_id)
        if base_id is None:
            return CavitationStage(None, _no_base_run(run_id), warn=True)
    note = unchecked_thruster(store, run_id, base_id, "base")
    return CavitationStage(base_id, notes=(note,) if note else ())


def training_runs(store: Store, run_id: str, refs: Sequence[str]) -> list[str]:
    """Full ids of the extra training runs `refs` for `run_id`'s model; UsageError for one
    that is `run_id` itself, repeated, of another thruster id, or not a shallow run with speed
    and current feedback."""
    ids = []
    for ref in refs:
        rid = store.resolve_run_id(ref)
        problem = ("it is the run being calibrated" if rid == run_id else
                   "it is given twice" if rid in ids else
                   cavitation_applicable(store, rid) or _other_thruster(store, run_id, rid))
        if problem:
            raise UsageError(f"--train-with {ref}: {problem}")
        ids.append(rid)
    return ids
