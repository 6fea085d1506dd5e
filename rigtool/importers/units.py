"""Unit suffixes in column headers ("Thrust (kgf)", "Speed [rpm]") and factors to rigtool's SI units."""

from __future__ import annotations

import math
import re

from rigtool.errors import UsageError

_SUFFIX = re.compile(r"^\s*(?P<name>.*?)\s*[(\[]\s*(?P<unit>[^)\]]*?)\s*[)\]]\s*$")

G0 = 9.80665
# quantity -> {normalised unit: factor to the stored SI unit}
FACTORS: dict[str, dict[str, float]] = {
    "time": {"s": 1.0, "sec": 1.0, "ms": 1e-3, "us": 1e-6, "min": 60.0},
    "thrust": {"n": 1.0, "kn": 1e3, "kgf": G0, "kg": G0, "gf": G0 / 1000, "g": G0 / 1000,
               "lbf": 4.4482216152605, "lb": 4.4482216152605, "ozf": 0.27801385095378},
    "speed": {"rpm": 1.0, "r/min": 1.0, "rps": 60.0, "hz": 60.0, "rad/s": 60.0 / (2 * math.pi),
              "erpm": 1.0},
    "current": {"a": 1.0, "ma": 1e-3},
    "voltage": {"v": 1.0, "mv": 1e-3},
    "depth": {"m": 1.0, "cm": 1e-2, "mm": 1e-3},
}
FACTORS["supply"] = FACTORS["voltage"]
FACTORS["thrust_std"] = FACTORS["thrust"]
# torque about the thrust axis, to N m; the product sign is written many ways (N·m, N⋅m, N.m, Nm)
_TORQUE_UNITS = {("n", "m"): 1.0, ("mn", "m"): 1e-3, ("n", "cm"): 1e-2, ("n", "mm"): 1e-3,
                 ("kgf", "m"): G0, ("kgf", "cm"): G0 / 100, ("gf", "cm"): G0 / 1e5,
                 ("lbf", "in"): 0.1129848290276167, ("lbf", "ft"): 1.3558179483314004,
                 ("ozf", "in"): 0.00706155181422604}
FACTORS["torque"] = {f"{a}{sep}{b}": k for (a, b), k in _TORQUE_UNITS.items()
                     for sep in ("·", "⋅", ".", "*", "-", "")}
# temperature, to °C: value * factor + OFFSETS (K and °F need an offset, not only a factor)
FACTORS["temperature"] = {"°c": 1.0, "c": 1.0, "degc": 1.0, "celsius": 1.0, "k": 1.0,
                          "°f": 5 / 9, "f": 5 / 9, "degf": 5 / 9}
OFFSETS = {"temperature": {"k": -273.15, "°f": -32 * 5 / 9, "f": -32 * 5 / 9,
                           "degf": -32 * 5 / 9}}
DEFAULT_UNITS = {"time": "s", "thrust": "n", "speed": "rpm", "current": "a", "voltage": "v",
                 "depth": "m", "supply": "v", "thrust_std": "n", "torque": "n·m",
                 "temperature": "°c"}
# header unit -> rigtool command unit; `volts`: an analog throttle (`Throttle (V)`, 0.5-4.5 V)
COMMAND_UNITS = {"us": "pulse_us", "pulse_us": "pulse_us", "%": "percent", "percent": "percent",
                 "pwm": "pwm_counts", "pwm_counts": "pwm_counts", "counts": "pwm_counts",
                 "rpm": "rpm", "a": "amps", "amps": "amps", "v": "volts", "volts": "volts"}
KNOWN_COMMAND_UNITS = tuple(dict.fromkeys(COMMAND_UNITS.values()))  # what --command-unit takes


def split_header(header: str) -> tuple[str, str | None]:
    """'Thrust (kgf)' -> ('Thrust', 'kgf'); a header without a unit suffix -> (header, None)."""
    m = _SUFFIX.match(header)
    if m and m.group("name"):
        return m.group("name"), m.group("unit")
    return header.strip(), None


def normalise(unit: str) -> str:
    """Lower-case, micro sign as 'u', ordinal º as degree sign, no spaces: 'µs' -> 'us',
    'N·m' -> 'n·m', 'ºC' -> '°c'."""
    return (unit.strip().lower().replace("µ", "u").replace("μ", "u").replace("º", "°")
            .replace(" ", ""))


def factor(quantity: str, unit: str | None) -> float:
    """Multiplier from `unit` to the stored SI unit of `quantity` (its default unit if None)."""
    key = normalise(unit) if unit else DEFAULT_UNITS[quantity]
    table = FACTORS[quantity]
    if key not in table:
        raise UsageError(f"unknown unit {unit!r} for {quantity}; known: {', '.join(sorted(table))}")
    return table[key]


def offset(quantity: str, unit: str | None) -> float:
    """What to add after the factor to reach the stored unit (temperature in K or °F: °C)."""
    key = normalise(unit) if unit else DEFAULT_UNITS[quantity]
    return OFFSETS.get(quantity, {}).get(key, 0.0)


def command_unit(unit: str | None) -> str | None:
    """The rigtool command unit for a header unit ('µs' -> 'pulse_us'), None if not known."""
    return COMMAND_UNITS.get(normalise(unit)) if unit else None
