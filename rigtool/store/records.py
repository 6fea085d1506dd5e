"""What the store takes in and hands out: run statuses, the point record the engine writes,
the typed run record, and a stored point's columns under their public names."""

from __future__ import annotations

from dataclasses import dataclass

RUN_STATUSES = ("running", "completed", "aborted", "failed", "interrupted")

STAT_FIELDS = ("thrust_n", "speed_rpm", "current_a")  # sample columns a point row has stats of

# A stored point's columns under the names the API, points.csv and the exports use
# (public name -> steps column). Statistics here are over all of a point's samples.
POINT_COLUMNS = {
    "step_idx": "idx", "command": "command", "depth_m": "depth_m", "voltage_set_v": "voltage_v",
    "repeat": "repeat",
    "direction": "direction", "status": "status", "settled": "settled",
    "t_start_s": "t_start_s", "t_acquire_s": "t_acquire_s", "t_end_s": "t_end_s",
    "settle_s": "settle_s", "rate_hz": "rate_hz", "n_samples": "n",
    **{f"{ch}_{stat}_{u}": f"{field}_{stat}"
       for field, ch, u in (("thrust_n", "thrust", "n"), ("speed_rpm", "speed", "rpm"),
                            ("current_a", "current", "a"))
       for stat in ("mean", "std", "min", "max")},
}
TEXT_POINT_COLUMNS = ("direction", "status")
INT_POINT_COLUMNS = ("step_idx", "repeat", "settled", "n_samples")


@dataclass(frozen=True)
class RunRecord:
    """One stored run, typed: what analysis and the API need without digging in JSON.

    `neutral` is the actuator's recorded neutral; older and imported runs fall back to the
    protocol's `command.neutral`, then to the usual neutral of the unit.
    """

    id: str
    name: str
    status: str
    created_utc: str
    finished_utc: str | None
    stop_reason: str | None
    tool_version: str
    seed: int | None
    n_planned: int
    command_unit: str
    neutral: float
    command_min: float | None
    command_max: float | None
    thruster_id: str | None
    propeller_diameter_m: float | None
    water_density_kg_m3: float | None
    rig_name: str | None
    metadata: dict
    protocol: dict
    rig: dict


@dataclass
class StepRecord:
    """One completed point, as the engine hands it to the store."""

    idx: int
    command: float
    command_unit: str
    depth_m: float | None
    repeat: int
    direction: str
    t_start_s: float
    t_acquire_s: float
    t_end_s: float
    settle_s: float
    settled: bool
    rate_hz: float
    status: str = "ok"
    counters: dict | None = None  # transport counters added during the point, by device role
    voltage_v: float | None = None  # supply voltage set for the point (None: not swept)
