"""Where each protocol limit gets its readings on a rig, so a limit without data is refused.

Judged from the rig file alone (a dry run opens nothing): the actuator's feedback, whether
the sensor measures torque or carries a temperature field, and whether a supply that the run
programs measures its own terminals.
"""

from __future__ import annotations

from pathlib import Path

from rigtool.config import locate
from rigtool.devices.base import ActuatorInfo
from rigtool.protocol import Protocol
from rigtool.rig import Rig


def _supply_measures(protocol: Protocol, rig: Rig) -> bool:
    """Whether the run programs a supply that measures its terminals (only a preset voltage
    sweep opens the supply; the simulator's supply measures)."""
    if protocol.voltage is None or protocol.voltage.mode != "preset":
        return False
    return rig.simulator is not None or (rig.supply is not None
                                         and rig.supply.measures_supply)


def _sensor_torque(rig: Rig) -> bool:
    """Whether the sensor measures torque (the twin's does; a driver declares it on its config)."""
    return rig.simulator is not None or (rig.sensor is not None and rig.sensor.measures_torque)


def _sensor_temperature(rig: Rig) -> bool:
    """Whether the sensor, as configured, reads a temperature (declared on its config)."""
    return rig.sensor is not None and rig.sensor.temperature_source()


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
        missing["max_torque_nm"] = "no torque: the sensor measures force only"
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
