"""Which classes implement each `driver:` name of a rig file, for each device role: the one list.

A table of name -> (module, driver class, config model), as python-can keeps for its
interfaces. The rig schema (rig.py) is built from it, so adding a driver is its module plus
one line here; what the driver can measure is declared on its config model
(devices/capabilities.py). Driver modules are imported when the rig schema is built; the
transport libraries they use (pyserial, python-can, cantools, pyvisa) load only when a driver
opens a port or a bus.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, NamedTuple

if TYPE_CHECKING:
    from pydantic import BaseModel

    from rigtool.devices.base import ActuatorInfo, Device


class Driver(NamedTuple):
    """Where a driver lives: its module, its device class and its rig-section config model."""

    module: str
    cls: str
    config: str


# role -> driver name -> where it lives
DRIVERS: dict[str, dict[str, Driver]] = {
    "actuator": {
        "stm32-bridge": Driver("rigtool.devices.stm32_bridge", "Stm32Bridge", "Stm32BridgeConfig"),
        "vesc-can": Driver("rigtool.devices.vesc_can", "VescCanDriver", "VescCanConfig"),
        "dbc-can": Driver("rigtool.devices.dbc_can", "DbcCanDriver", "DbcCanConfig"),
    },
    "sensor": {
        "ati-netft": Driver("rigtool.devices.netft", "NetFTSensor", "NetFTConfig"),
        "ascii-gauge": Driver("rigtool.devices.ascii_gauge", "AsciiGauge", "AsciiGaugeConfig"),
    },
    "depth_stage": {
        "serial-stage": Driver("rigtool.devices.serial_stage", "SerialStage", "SerialStageConfig"),
    },
    "carriage": {
        "serial-carriage": Driver("rigtool.devices.serial_carriage", "SerialCarriage",
                                  "SerialCarriageConfig"),
    },
    "supply": {
        "scpi-supply": Driver("rigtool.devices.scpi_supply", "ScpiSupply", "ScpiSupplyConfig"),
    },
}


def _entry(role: str, name: str) -> Driver:
    """The table entry of driver `name` in `role`; KeyError names the drivers the role has."""
    try:
        return DRIVERS[role][name]
    except KeyError:
        known = ", ".join(DRIVERS.get(role, ()))
        raise KeyError(f"no {role} driver {name!r} (known: {known})") from None


def driver_class(role: str, name: str) -> type[Device]:
    """The class of driver `name` in `role` (its module imported now)."""
    entry = _entry(role, name)
    return getattr(importlib.import_module(entry.module), entry.cls)


def config_models(role: str) -> tuple[type[BaseModel], ...]:
    """The rig-section config model of every driver of `role`, in table order (the schema's
    discriminated union is built from them)."""
    return tuple(getattr(importlib.import_module(e.module), e.config)
                 for e in DRIVERS[role].values())


def driver_modules() -> set[str]:
    """Every registered driver's module (the layering test keeps them apart)."""
    return {e.module for table in DRIVERS.values() for e in table.values()}


def open_device(role: str, config: BaseModel) -> Device:
    """Open the driver that a rig-file section names in its `driver:` field."""
    return driver_class(role, config.driver)(config)


def actuator_info(config: BaseModel) -> ActuatorInfo:
    """An actuator's command space from its rig-file section alone: a dry run opens nothing."""
    return driver_class("actuator", config.driver).info_for(config)
