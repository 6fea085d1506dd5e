"""Which class implements each `driver:` name of a rig file, for each device role.

A table of name -> (module, class), as python-can keeps for its interfaces: a driver's class
is looked up, and its module imported, only when a rig opens it. Each section's config model
is part of the rig schema (rig.py); `tests/test_device_base.py` checks that both list the
same names.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from pydantic import BaseModel

    from rigtool.devices.base import ActuatorInfo, Device

# role -> driver name -> (module, class)
DRIVERS: dict[str, dict[str, tuple[str, str]]] = {
    "actuator": {
        "stm32-bridge": ("rigtool.devices.stm32_bridge", "Stm32Bridge"),
        "vesc-can": ("rigtool.devices.vesc_can", "VescCanDriver"),
        "dbc-can": ("rigtool.devices.dbc_can", "DbcCanDriver"),
    },
    "sensor": {
        "ati-netft": ("rigtool.devices.netft", "NetFTSensor"),
        "ascii-gauge": ("rigtool.devices.ascii_gauge", "AsciiGauge"),
    },
    "depth_stage": {
        "serial-stage": ("rigtool.devices.serial_stage", "SerialStage"),
    },
    "carriage": {
        "serial-carriage": ("rigtool.devices.serial_carriage", "SerialCarriage"),
    },
    "supply": {
        "scpi-supply": ("rigtool.devices.scpi_supply", "ScpiSupply"),
    },
}


def driver_class(role: str, name: str) -> type[Device]:
    """The class of driver `name` in `role` (its module imported now); KeyError names the
    drivers the role has."""
    try:
        module, cls = DRIVERS[role][name]
    except KeyError:
        known = ", ".join(DRIVERS.get(role, ()))
        raise KeyError(f"no {role} driver {name!r} (known: {known})") from None
    return getattr(importlib.import_module(module), cls)


def open_device(role: str, config: BaseModel) -> Device:
    """Open the driver that a rig-file section names in its `driver:` field."""
    return driver_class(role, config.driver)(config)


def actuator_info(config: BaseModel) -> ActuatorInfo:
    """An actuator's command space from its rig-file section alone: a dry run opens nothing."""
    return driver_class("actuator", config.driver).info_for(config)
