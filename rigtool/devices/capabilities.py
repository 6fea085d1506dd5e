"""What a device can measure, declared on its rig-file config model, so the rig, the limit
checks and the dry run read capabilities instead of comparing driver names.

A sensor's or a supply's config model subclasses the section below; the defaults are the
cautious ones (a new sensor measures one force axis, no torque, no temperature, states no
rate; a new supply measures nothing), so a limit without data is refused, not left unwatched.
"""

from __future__ import annotations

from typing import ClassVar

from pydantic import BaseModel


class SensorSection(BaseModel):
    """A force sensor's rig-file section and what the sensor measures."""

    axes: ClassVar[int] = 1  # F/T channels measured: 1 (a single-axis gauge) or 6
    measures_torque: ClassVar[bool] = False

    def temperature_source(self) -> bool:
        """Whether this sensor, as configured, also reads a temperature (`temperature_c`)."""
        return False

    def stated_rate(self) -> str | None:
        """Where the sensor, as configured, states its own sample rate (None: it does not)."""
        return None


class SupplySection(BaseModel):
    """A programmable supply's rig-file section and whether it reads back volts and amps."""

    measures_supply: ClassVar[bool] = False
