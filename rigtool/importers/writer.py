"""Write imported points into the store as a completed run, through the Store's public API."""

from __future__ import annotations

from rigtool import __version__
from rigtool.analysis.dataset import NEUTRAL_BY_UNIT
from rigtool.importers.steps import ImportedStep
from rigtool.store import StepRecord, Store


def protocol_for(name: str, command_unit: str, neutral: float | None, steps: list[ImportedStep],
                 metadata: dict, source: str) -> dict:
    """A protocol-shaped dict describing the imported run (what analysis and report read)."""
    commands = sorted({s.command for s in steps})
    return {
        "rigtool_protocol": 1,
        "name": name,
        "description": f"imported from {source}",
        "metadata": metadata,
        "command": {"unit": command_unit, "values": commands,
                    "neutral": NEUTRAL_BY_UNIT.get(command_unit, 0.0) if neutral is None else neutral,
                    "order": "as logged", "repeats": max((s.repeat for s in steps), default=1)},
        "depth": {"unit": "m", "values": sorted({s.depth_m for s in steps if s.depth_m is not None})},
    }


def write_run(store: Store, *, name: str, protocol: dict, rig: dict, steps: list[ImportedStep],
              events: list[tuple[str, dict]]) -> str:
    """Create the run, add every point with its samples and the import events; return the id."""
    unit = protocol["command"]["unit"]
    plan = [{"idx": i, "command": s.command, "depth_m": s.depth_m, "repeat": s.repeat,
             "direction": s.direction} for i, s in enumerate(steps)]
    run_id = store.create_run(name=name, protocol=protocol, protocol_path=None, rig=rig, plan=plan,
                              metadata=protocol["metadata"], seed=None, command_unit=unit,
                              tool_version=__version__)
    try:
        for kind, detail in events:
            store.add_event(run_id, kind, detail)
        for i, s in enumerate(steps):
            record = StepRecord(idx=i, command=s.command, command_unit=unit, depth_m=s.depth_m,
                                repeat=s.repeat, direction=s.direction, t_start_s=s.t_start_s,
                                t_acquire_s=s.t_acquire_s, t_end_s=s.t_end_s,
                                settle_s=s.settle_s, settled=True, rate_hz=s.rate_hz)
            store.add_step(run_id, record, s.samples)
    except BaseException:
        store.finish_run(run_id, "failed", "import stopped before every point was written")
        raise
    store.finish_run(run_id, "completed")
    return run_id
