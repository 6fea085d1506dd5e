"""Where each protocol limit gets its readings on a rig, so a limit without data is refused.

Judged from the rig file alone (a dry run opens nothing): the actuator's feedback, whether
the sensor measures torque or carries a temperature field, and whether a supply that the run
programs measures its own terminals.
"""

from __future__ import annotations

from pathlib import Path

from rigtool.config import locate
from rigtool.devices.ascii_gauge import has_temperature
from rigtool.devices.base import ActuatorInfo
from rigtool.protocol import Protocol
from rigtool.rig import Rig

MEASURING_SUPPLIES = ("scpi-supply",)  # drivers that read back volts and amps (`measure()`)


def _supply_measures(protocol: Protocol, rig: Rig) -> bool:
    """Whether the run programs a supply that measures its terminals (only a preset voltage
    sweep opens the supply; the simulator's supply measures)."""
    if protocol.voltage is None or protocol.voltage.mode != "preset":
        return False
    return rig.simulator is not None or (rig.supply is not None
                                         and rig.supply.driver in MEASURING_SUPPLIES)


def _sensor_torque(rig: Rig) -> bool:
    """Six-axis sensors (and the twin's) measure torque; single-axis gauges do not."""
    return rig.simulator is not None or getattr(rig.sensor, "driver", None) != "ascii-gauge"


def _sensor_temperature(rig: Rig) -> bool:
    sensor = rig.sensor
    return getattr(sensor, "driver", None) == "ascii-gauge" and has_temperature(sensor)


def missing_sources(protocol: Protocol, rig: Rig, info: ActuatorInfo) -> dict[str, str]:
    """Limits the protocol sets that no device of this rig can feed: field -> what is missing."""
    fb = set(info.feedback)
    supply = _supply_measures(protocol, rig)
    limits = protocol.limits
    missing = {}
    if "voltage_v" not in fb and not supply:
        why = ("no bus voltage: the actuator reports no voltage_v and no measuring supply "
               "is programmed by this protocol (a preset `voltage:` sweep)")
        for name in ("min_bus_v", "max_bus_v"):
            if getattr(limits, name) is not None:
                missing[name] = why
    if limits.max_power_w is not None and not ({"voltage_v", "current_a"} <= fb or supply):
        missing["max_power_w"] = ("no power: the actuator does not report both voltage_v and "
                                  "current_a, and no measuring supply is programmed")
    if limits.max_torque_nm is not None and not _sensor_torque(rig):
        missing["max_torque_nm"] = "no torque: the single-axis gauge measures force only"
    if limits.max_temperature_c is not None and "temperature_c" not in fb \
            and not _sensor_temperature(rig):
        missing["max_temperature_c"] = (
            "no temperature channel: add a `temperature_c` group to the gauge's pattern or the "
            "bridge's telemetry_regex, or a `thermistor_counts` group with a `thermistor:` "
            "section")
    return missing


def source_problems(protocol: Protocol, path: Path, rig: Rig, info: ActuatorInfo) -> list[str]:
    """One file:line message per limit without a data source on `rig`."""
    return [f"{locate(path, ('limits', name))}: limits.{name}: rig {rig.name!r} has no data "
            f"source for this limit ({why})"
            for name, why in missing_sources(protocol, rig, info).items()]
