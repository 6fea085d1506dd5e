"""Shared vocabulary, defined once: command units, how they are printed, their neutral, the
force/torque channel names, the force and torque units devices report in, and the
thrust-speed laws a calibration may choose."""

from __future__ import annotations

from collections.abc import Mapping

# The thrust-speed laws a calibration may choose per direction, and each one's parameters
# (rigtool.models.laws evaluates them).
THRUST_LAWS = {"quadratic": ("C_p",), "quadratic+linear": ("C_p", "C_l"), "power": ("C", "k")}
FT_CHANNELS = ("fx", "fy", "fz", "tx", "ty", "tz")  # N and N m, in the sensor frame
COMMAND_UNITS = ("percent", "pwm_counts", "pulse_us", "rpm", "amps")  # protocols and drivers
UNIT_LABEL = {"percent": "%", "pwm_counts": "PWM counts", "pulse_us": "µs", "rpm": "r/min",
              "amps": "A", "volts": "V"}  # volts: an analog throttle voltage (imports only)
NEUTRAL_BY_UNIT = {"percent": 0.0, "pwm_counts": 0.0, "pulse_us": 1500.0, "rpm": 0.0,
                   "amps": 0.0, "volts": 0.0}


def unit_label(unit: str) -> str:
    """How a command unit is printed (the unit itself when it has no label)."""
    return UNIT_LABEL.get(unit, unit)


# One unit of each, in N or N m. Keys are normalised by _unit_key (lower case, no separators).
FORCE_UNITS_N = {
    "n": 1.0, "kn": 1e3, "mn": 1e-3,
    "lbf": 4.4482216152605, "lb": 4.4482216152605, "klbf": 4448.2216152605, "klb": 4448.2216152605,
    "kgf": 9.80665, "kg": 9.80665, "gf": 0.00980665, "g": 0.00980665,
    "ozf": 0.27801385095378125, "oz": 0.27801385095378125,
}  # fmt: skip
TORQUE_UNITS_NM = {
    "nm": 1.0, "nmm": 1e-3, "knm": 1e3,
    "lbfin": 0.1129848290276167, "lbin": 0.1129848290276167, "inlb": 0.1129848290276167,
    "inlbf": 0.1129848290276167, "lbfft": 1.3558179483314004, "lbft": 1.3558179483314004,
    "ftlb": 1.3558179483314004, "ftlbf": 1.3558179483314004,
    "kgfcm": 0.0980665, "kgcm": 0.0980665, "kgfm": 9.80665, "gfcm": 0.0000980665,
    "ozfin": 0.00706155181422604, "ozin": 0.00706155181422604,
}  # fmt: skip


def _unit_key(unit: str) -> str:
    return "".join(c for c in unit.strip().lower() if c.isalnum())


def unit_factor(unit: str, table: Mapping[str, float], kind: str) -> float:
    """SI value of one `unit` (e.g. "lbf" -> 4.448); ValueError names the known units."""
    try:
        return table[_unit_key(unit)]
    except KeyError:
        raise ValueError(f"unknown {kind} unit {unit!r} (known: {', '.join(sorted(table))})") from None
