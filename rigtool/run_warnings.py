"""The warnings about a run and its calibration, gathered once: `calibrate` and `report`
print this list and the HTML report shows it, so they cannot disagree."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from rigtool.analysis.results import CalibrationResult
    from rigtool.store import Store

WARN_KINDS = ("limit_trip", "warning", "interrupt")
MAX_EVENT_LINES = 12


def run_warnings(run: dict, events: list[dict], cal: CalibrationResult | None,
                 extra: Sequence[str] = ()) -> list[str]:
    """Run status, warning events, calibration warnings (merged across depths), then `extra`."""
    out = []
    if run["status"] != "completed":
        reason = run.get("stop_reason") or "no reason recorded"
        out.append(f"Run {run['status']}: {reason}. The report covers the recorded points only.")
    noted = [e for e in events if e["kind"] in WARN_KINDS]
    out += [event_text(e) for e in noted[:MAX_EVENT_LINES]]
    if len(noted) > MAX_EVENT_LINES:
        out.append(f"... and {len(noted) - MAX_EVENT_LINES} more warning event(s)")
    if cal is None:
        out.append("No recorded points: nothing to calibrate.")
    else:
        out += group_by_depth(cal.warnings, [s.label for s in cal.sections])
    return out + list(extra)


def stored_run_warnings(store: Store, run_id: str, cal: CalibrationResult | None,
                        extra: Sequence[str] = ()) -> list[str]:
    """`run_warnings` of a stored run (reads its record and events)."""
    return run_warnings(store.run(run_id), store.events(run_id), cal, extra)


def event_text(event: dict) -> str:
    """One stored event as a line: kind, point, time and message (or details)."""
    detail = event.get("detail") or {}
    text = detail.get("message") or ", ".join(f"{k}={v}" for k, v in detail.items()) or "-"
    where = f" (point {event['step_idx']})" if event.get("step_idx") is not None else ""
    when = f" at t = {event['t_s']:.1f} s" if event.get("t_s") is not None else ""
    return f"{event['kind']}{where}{when}: {text}"


def group_by_depth(warnings: list[str], labels: list[str]) -> list[str]:
    """Merge "<depth>: text" warnings repeated at several depths into "<d1>, <d2>: text"."""
    prefixes = tuple(f"{label}: " for label in labels)
    merged: dict[str, list[str]] = {}
    for w in warnings:
        head = next((p for p in prefixes if w.startswith(p)), None)
        key = w[len(head):] if head else w
        merged.setdefault(key, []).append(head[:-2] if head else "")
    return [", ".join(d for d in depths if d) + ": " + text if any(depths) else text
            for text, depths in merged.items()]
