"""Write imported points into the store as a completed run, through the Store's public API.

The run is created already marked as an incomplete import (status `failed`, reason
INCOMPLETE) and only marked `completed` after its last point is committed, so an import
killed at any moment leaves either nothing or a run that says what it is.
"""

from __future__ import annotations

import numpy as np

from rigtool.importers.steps import ImportedPoints
from rigtool.store import Store
from rigtool.units import NEUTRAL_BY_UNIT
from rigtool.version import __version__

INCOMPLETE = ("incomplete import: rigtool import stopped before every point was written; "
              "re-import the file")


def protocol_for(name: str, command_unit: str, neutral: float | None, points: ImportedPoints,
                 metadata: dict, source: str, steps: bool = False) -> dict:
    """A protocol-shaped dict describing the imported run (what analysis and report read); a
    step log lists its levels as `command.steps`, which makes it a step-response run."""
    depths = points.depth_m[np.isfinite(points.depth_m)]
    voltages = points.voltage_v[np.isfinite(points.voltage_v)]
    doc = {
        "rigtool_protocol": 1,
        "name": name,
        "description": f"imported from {source}",
        "metadata": metadata,
        "command": {"unit": command_unit, "values": np.unique(points.command).tolist(),
                    "neutral": NEUTRAL_BY_UNIT.get(command_unit, 0.0) if neutral is None else neutral,
                    "order": "as logged", "repeats": int(points.repeat.max(initial=1))},
        "depth": {"unit": "m", "values": np.unique(depths).tolist()},
    }
    if voltages.size:
        doc["voltage"] = {"unit": "V", "values": np.unique(voltages).tolist(), "mode": "manual"}
    if steps:
        doc["command"]["steps"] = points.command.tolist()
        doc["timing"] = {"settle": {"seconds": 0}, "rest_s": 0}
    return doc


def _plan(points: ImportedPoints) -> list[dict]:
    """The stored plan: one entry per point, in file order (a supply voltage only where set)."""
    depth = [None if d != d else d for d in points.depth_m.tolist()]
    plan = [{"idx": i, "command": c, "depth_m": d, "repeat": r, "direction": s}
            for i, (c, d, r, s) in enumerate(zip(points.command.tolist(), depth,
                                                 points.repeat.tolist(),
                                                 points.direction.tolist(), strict=True))]
    for step, v in zip(plan, points.voltage_v.tolist(), strict=True):
        if v == v:
            step["voltage_v"] = v
    return plan


def write_run(store: Store, *, name: str, protocol: dict, rig: dict, points: ImportedPoints,
              events: list[tuple[str, dict]]) -> str:
    """Create the run, add the import events and every point with its samples; return the id."""
    unit = protocol["command"]["unit"]
    run_id = store.create_run(name=name, protocol=protocol, protocol_path=None, rig=rig,
                              plan=_plan(points), metadata=protocol["metadata"], seed=None,
                              command_unit=unit, tool_version=__version__, status="failed",
                              stop_reason=INCOMPLETE)
    store.add_events(run_id, events)
    store.add_points(run_id, points.columns(), points.bounds, points.samples, unit)
    store.finish_run(run_id, "completed")
    return run_id
