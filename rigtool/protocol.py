"""The protocol file: what to sweep and how to measure each point.

Validated strictly by pydantic: unknown fields are errors, so a typo can never
silently change an experiment. Units are explicit in the file and converted to SI here.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    NonNegativeFloat,
    PositiveFloat,
    PositiveInt,
    model_validator,
)

from rigtool.config import load_model
from rigtool.devices.base import COMMAND_UNITS

CommandUnit = Literal["percent", "pwm_counts", "pulse_us", "rpm", "amps"]
assert set(CommandUnit.__args__) == set(COMMAND_UNITS)  # type: ignore[attr-defined]

DEPTH_TO_M = {"m": 1.0, "cm": 0.01, "mm": 0.001}


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class CommandRange(_Strict):
    """Evenly spaced commands from start to stop inclusive."""

    start: float
    stop: float
    step: PositiveFloat

    @model_validator(mode="after")
    def _ordered(self) -> CommandRange:
        if self.stop < self.start:
            raise ValueError(f"stop ({self.stop}) must not be below start ({self.start}); "
                             "use order: down to sweep downwards")
        if (self.stop - self.start) / self.step > 100_000:
            raise ValueError("more than 100000 commands: check start/stop/step")
        return self

    def values(self) -> list[float]:
        n = int(round((self.stop - self.start) / self.step + 1e-9)) + 1
        vals = [round(self.start + i * self.step, 9) for i in range(n)]
        return [v for v in vals if v <= self.stop + 1e-9]


class CommandAxis(_Strict):
    """The swept command: unit, values (list or range), order and repeats."""

    unit: CommandUnit
    values: list[float] | None = Field(default=None, min_length=1)
    range: CommandRange | None = None
    order: Literal["up", "down", "up-down", "random"] = "up"
    repeats: PositiveInt = 1
    seed: int = 0

    @model_validator(mode="after")
    def _one_source(self) -> CommandAxis:
        if (self.values is None) == (self.range is None):
            raise ValueError("give exactly one of `values` (a list) or `range` (start/stop/step)")
        return self

    def command_values(self) -> list[float]:
        return sorted(self.values) if self.values is not None else self.range.values()  # type: ignore[union-attr]


class DepthAxis(_Strict):
    """Immersion depths of the propeller centre below the surface."""

    unit: Literal["m", "cm", "mm"]
    values: list[NonNegativeFloat] = Field(min_length=1)
    mode: Literal["preset", "manual", "stage"] = "preset"
    loop: Literal["outer", "inner"] = "outer"

    def depths_m(self) -> list[float]:
        return [round(v * DEPTH_TO_M[self.unit], 9) for v in self.values]


class SteadySettle(_Strict):
    """Settle until the thrust mean of two consecutive windows differs by < tolerance."""

    window_s: PositiveFloat = 0.5
    tolerance_n: PositiveFloat = 0.1
    min_s: NonNegativeFloat = 0.0
    timeout_s: PositiveFloat = 10.0


class Settle(_Strict):
    """Either a fixed wait or a settling criterion on thrust."""

    seconds: NonNegativeFloat | None = None
    until_steady: SteadySettle | None = None

    @model_validator(mode="after")
    def _one(self) -> Settle:
        if (self.seconds is None) == (self.until_steady is None):
            raise ValueError("give exactly one of `seconds` or `until_steady`")
        return self

    def max_seconds(self) -> float:
        """Longest settle: the engine reads min_s, then windows until two agree or the time
        since the start reaches timeout_s (it always compares at least two windows)."""
        if self.seconds is not None:
            return self.seconds
        c = self.until_steady
        assert c is not None
        loops = max(1, math.ceil((c.timeout_s - c.min_s) / c.window_s - 1e-9) - 1)
        return c.min_s + c.window_s * (loops + 1)


class Acquire(_Strict):
    """How much to record per point: N samples or T seconds, at a rate."""

    rate_hz: PositiveFloat
    samples: PositiveInt | None = None
    seconds: PositiveFloat | None = None

    @model_validator(mode="after")
    def _one(self) -> Acquire:
        if (self.samples is None) == (self.seconds is None):
            raise ValueError("give exactly one of `samples` or `seconds`")
        return self

    @property
    def n_samples(self) -> int:
        return self.samples if self.samples is not None else max(1, round(self.seconds * self.rate_hz))  # type: ignore[operator]


class Timing(_Strict):
    """Per-point timing: settle, acquire, rest at neutral, and when to re-tare."""

    settle: Settle
    acquire: Acquire
    rest_s: NonNegativeFloat = 0.0
    tare: Literal["never", "at_start", "per_depth", "per_point"] = "at_start"
    tare_s: PositiveFloat = 1.0


class Limits(_Strict):
    """Safety limits checked on every sample block; a trip sends the actuator to neutral."""

    max_thrust_n: PositiveFloat | None = None
    max_current_a: PositiveFloat | None = None
    max_speed_rpm: PositiveFloat | None = None
    max_staleness_s: PositiveFloat = 1.0
    slew_per_s: PositiveFloat | None = None
    debounce_samples: PositiveInt = 5
    on_trip: Literal["abort", "pause"] = "abort"  # pause: neutral, ask the operator, retry the point


class Metadata(_Strict):
    """Stored with the run; diameter and density enable K_T in calibrations."""

    thruster_id: str | None = None
    propeller: str | None = None
    operator: str | None = None
    notes: str | None = None
    propeller_diameter_m: PositiveFloat | None = None
    water_density_kg_m3: PositiveFloat | None = None
    extra: dict[str, str] = Field(default_factory=dict)


class SimulatorSpec(_Strict):
    """Which simulator twin profile to run with `--sim`, its seed and parameter overrides."""

    profile: str
    seed: int = 1
    overrides: dict[str, float | str] = Field(default_factory=dict)


class Protocol(_Strict):
    """A whole sweep protocol file."""

    rigtool_protocol: Literal[1] = 1
    name: str = Field(min_length=1)
    description: str = ""
    rig: str | None = None
    simulator: SimulatorSpec | None = None
    metadata: Metadata = Field(default_factory=Metadata)
    command: CommandAxis
    depth: DepthAxis
    timing: Timing
    limits: Limits = Field(default_factory=Limits)


def load_protocol(path: str | Path) -> tuple[Protocol, dict]:
    """Read and validate a protocol file; ConfigError names file, line and field."""
    return load_model(Path(path), Protocol)
