"""The vehicle file: rigid body, centres of gravity and buoyancy, and each thruster's mount.

Body axes are Fossen's (x forward, y starboard, z down), origin at the centre of gravity's
reference point; every length in metres. A thruster's `calibration` is a folder written by
`rigtool calibrate`, taken relative to the vehicle file.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from rigtool.config import FieldError, load_model

Length = Annotated[float, Field(ge=-100.0, le=100.0)]
Vector = tuple[Length, Length, Length]
Name = Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")]
UNIT_SLACK = 0.01  # a thruster direction's length may differ from 1 by this much


class VehicleThruster(BaseModel):
    """One thruster: where it pushes, which way positive thrust points, and its calibration."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    name: Name
    position_m: Vector
    direction: Vector
    calibration: str = Field(min_length=1, max_length=4096)
    column: Name | None = None
    depth_m: Annotated[float, Field(ge=0.0, le=1000.0)] | None = None  # calibration depth
    lag_s: Annotated[float, Field(ge=0.0, le=10.0)] | None = None  # command to thrust

    @field_validator("direction")
    @classmethod
    def _unit(cls, v: tuple[float, float, float]) -> tuple[float, float, float]:
        norm = math.sqrt(sum(x * x for x in v))
        if abs(norm - 1.0) > UNIT_SLACK:
            raise ValueError(f"must be a unit vector (its length is {norm:.4g}); positive thrust "
                             "points along it in body axes")
        return tuple(x / norm for x in v)

    @property
    def log_column(self) -> str:
        """The log column holding this thruster's command."""
        return self.column or self.name


class Vehicle(BaseModel):
    """A whole vehicle file."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    rigtool_vehicle: Literal[1] = 1
    name: str = Field(min_length=1, max_length=200)
    mass_kg: Annotated[float, Field(gt=0.0, le=1e6)]
    inertia_kg_m2: tuple[Annotated[float, Field(gt=0.0, le=1e7)], ...] = Field(
        min_length=3, max_length=3)
    cog_m: Vector = (0.0, 0.0, 0.0)
    cob_m: Vector
    buoyancy_n: Annotated[float, Field(gt=0.0, le=1e8)]
    gravity_m_s2: Annotated[float, Field(gt=9.7, lt=9.9)] = 9.81
    water_density_kg_m3: Annotated[float, Field(ge=990.0, le=1050.0)] = 1000.0
    thrusters: list[VehicleThruster] = Field(min_length=1, max_length=32)

    @model_validator(mode="after")
    def _distinct(self) -> Vehicle:
        for what, field, values in (("name", "name", [t.name for t in self.thrusters]),
                                    ("column", "column", [t.log_column for t in self.thrusters])):
            second = next((i for i, v in enumerate(values) if v in values[:i]), None)
            if second is not None:
                dup = sorted({v for v in values if values.count(v) > 1})
                raise FieldError(("thrusters", second, field),
                                 f"thrusters share a {what}: {', '.join(dup)}")
        if any(self.cog_m):
            raise FieldError(("cog_m",), "cog_m must be (0, 0, 0): body axes have their origin at "
                             "the centre of gravity (give positions and cob_m from it)")
        return self

    @property
    def weight_n(self) -> float:
        """Weight in water's gravity: mass times g."""
        return self.mass_kg * self.gravity_m_s2


def load_vehicle(path: str | Path) -> tuple[Vehicle, dict[str, Path]]:
    """Read and validate a vehicle file; ConfigError names file, line and field. Also gives
    each thruster's calibration folder, resolved relative to the file."""
    path = Path(path)
    vehicle, _ = load_model(path, Vehicle)
    folders = {t.name: (path.parent / t.calibration) for t in vehicle.thrusters}
    return vehicle, folders
