"""Shared vocabulary, defined once: command units, how they are printed, their neutral, and
the force/torque channel names."""

from __future__ import annotations

FT_CHANNELS = ("fx", "fy", "fz", "tx", "ty", "tz")  # N and N m, in the sensor frame
COMMAND_UNITS = ("percent", "pwm_counts", "pulse_us", "rpm", "amps")
UNIT_LABEL = {"percent": "%", "pwm_counts": "PWM counts", "pulse_us": "µs", "rpm": "r/min",
              "amps": "A"}
NEUTRAL_BY_UNIT = {"percent": 0.0, "pwm_counts": 0.0, "pulse_us": 1500.0, "rpm": 0.0,
                   "amps": 0.0}


def unit_label(unit: str) -> str:
    """How a command unit is printed (the unit itself when it has no label)."""
    return UNIT_LABEL.get(unit, unit)
