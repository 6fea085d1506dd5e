"""Tyto Robotics / RCbenchmark thrust-stand CSV logs: recognise their headers, map their columns.

Their logs name each column with a unit suffix, e.g. `Time (s)`, `ESC signal (µs)` (older
software: `ESC (µs)`), `Thrust (kgf)` or `Thrust (N)`, `Torque (N·m)`, `Voltage (V)`,
`Current (A)`, `Motor Electrical Speed (RPM)`, `Motor Optical Speed (RPM)`, and with
temperature probes a temperature column (`Temp0 (°C)`, `Temperature (°C)`, ...). Manufacturer
tables in the same style (Blue Robotics: `PWM (µs)`, `RPM`, `Current (A)`, `Voltage (V)`,
`Force (Kg f)`, and `Supply Voltage (V)` where one file holds several voltages) are read the
same way.
"""

from __future__ import annotations

import re

from rigtool.importers.units import split_header

# field -> header base names (lower case, unit suffix removed; whole-name regular
# expressions), most preferred first
PATTERNS: dict[str, tuple[str, ...]] = {
    "time": (r"time",),
    "command": (r"esc signal", r"esc", r"pwm", r"throttle"),
    "thrust": (r"thrust", r"force"),  # `Force (Kg f)`: manufacturer tables (Blue Robotics)
    "voltage": (r"voltage",),
    "depth": (r"depth",),  # rigtool's own performance.csv
    # the voltage set in a voltage sweep (performance.csv, manufacturer tables of several
    # voltages); recognised in every table, see ALWAYS_RECOGNISED
    "supply": (r"supply voltage", r"supply voltage set", r"set voltage", r"voltage set",
               r"supply"),
    "current": (r"current",),
    "speed": (r"motor optical speed", r"optical speed", r"motor speed", r"rpm",
              r"motor electrical speed", r"electrical speed"),
    "torque": (r"torque", r"motor torque", r"reaction torque"),
    # a probe's temperature: `Temperature`, `Temp`, `Temp0`, `Temp 1`, `Motor Temperature`...
    "temperature": (r"(?:motor |winding |esc |water |ambient |coil )?temp(?:erature)?"
                    r"(?: ?(?:probe )?\d{1,2})?",),
}
ELECTRICAL = re.compile(r"electrical", re.IGNORECASE)
ELECTRICAL_SPEED = (r"motor electrical speed", r"electrical speed")  # eRPM, most preferred first
ALWAYS_RECOGNISED = ("supply",)  # recognised by header in any table, with a mapping too


def detect(header: list[str]) -> bool:
    """True if the header looks like a Tyto/RCbenchmark log (an ESC and a thrust column)."""
    found = guess_columns(header)
    return "command" in found and "thrust" in found


def guess_columns(header: list[str]) -> dict[str, str]:
    """Field -> header cell for the columns this format is known to use."""
    bases = [split_header(h)[0].lower() for h in header]
    out: dict[str, str] = {}
    for field, names in PATTERNS.items():
        for name in names:
            hit = next((h for h, b in zip(header, bases, strict=True)
                        if re.fullmatch(name, b)), None)
            if hit is not None:
                out[field] = hit
                break
    return out


def electrical_speed_column(header: list[str]) -> str | None:
    """The eRPM column of a log, if any: read beside the optical speed to check either."""
    bases = [split_header(h)[0].lower() for h in header]
    return next((h for name in ELECTRICAL_SPEED
                 for h, b in zip(header, bases, strict=True) if re.fullmatch(name, b)), None)


def is_electrical(header_cell: str) -> bool:
    """True for the eRPM column (needs the motor's pole pairs to give propeller speed)."""
    return bool(ELECTRICAL.search(header_cell))
