"""What the store takes in and hands out: run statuses, the point record the engine writes,
the typed run record, and a stored point's columns under their public names."""

from __future__ import annotations

from dataclasses import dataclass

RUN_STATUSES = ("running", "completed", "aborted", "failed", "interrupted")

STAT_FIELDS = ("thrust_n", "speed_rpm", "current_a")  # sample columns a point row has stats of
POINT_STATS = ("mean", "std", "min", "max")


def stat_column(field: str, stat: str) -> str:
    """The name of a point's statistic over all of its samples, e.g. `thrust_all_mean_n`: the
    same in the steps table, the API and the exports; `all` sets it apart from the steady
    window's `thrust_mean_n` of a calibration's points.csv."""
    channel, unit = field.rsplit("_", 1)
    return f"{channel}_all_{stat}_{unit}"


# A stored point's columns under the names the API and the exports use (public name -> steps
# column; since schema version 9 they differ only in step_idx and n_samples).
POINT_COLUMNS = {
    "step_idx": "idx", "command": "command", "depth_m": "depth_m",
    "voltage_set_v": "voltage_set_v", "repeat": "repeat",
    "direction": "direction", "status": "status", "settled": "settled",
    "t_start_s": "t_start_s", "t_acquire_s": "t_acquire_s", "t_end_s": "t_end_s",
    "settle_s": "settle_s", "rate_hz": "rate_hz", "n_samples": "n",
    **{stat_column(f, s): stat_column(f, s) for f in STAT_FIELDS for s in POINT_STATS},
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
