"""Which driver implements which `driver:` name of a rig file, for each device role."""

from __future__ import annotations

from typing import Annotated, Union

from pydantic import Field

from rigtool.devices import dbc_can, stm32_bridge, vesc_can
from rigtool.devices.ascii_gauge import AsciiGauge, AsciiGaugeConfig
from rigtool.devices.dbc_can import DbcCanConfig, DbcCanDriver
from rigtool.devices.netft import NetFTConfig, NetFTSensor
from rigtool.devices.scpi_supply import ScpiSupply, ScpiSupplyConfig
from rigtool.devices.serial_stage import SerialStage, SerialStageConfig
from rigtool.devices.stm32_bridge import Stm32Bridge, Stm32BridgeConfig
from rigtool.devices.vesc_can import VescCanConfig, VescCanDriver

ACTUATORS = {"stm32-bridge": Stm32Bridge, "vesc-can": VescCanDriver, "dbc-can": DbcCanDriver}
# the command space of each actuator from its rig-file section alone: a dry run opens nothing
ACTUATOR_INFO = {"stm32-bridge": stm32_bridge.actuator_info, "vesc-can": vesc_can.actuator_info,
                 "dbc-can": dbc_can.actuator_info}
SENSORS = {"ati-netft": NetFTSensor, "ascii-gauge": AsciiGauge}
STAGES = {"serial-stage": SerialStage}
SUPPLIES = {"scpi-supply": ScpiSupply}

ActuatorConfig = Annotated[
    Union[Stm32BridgeConfig, VescCanConfig, DbcCanConfig], Field(discriminator="driver")  # noqa: UP007
]
SensorConfig = Annotated[Union[NetFTConfig, AsciiGaugeConfig], Field(discriminator="driver")]  # noqa: UP007
StageConfig = Annotated[Union[SerialStageConfig], Field(discriminator="driver")]  # noqa: UP007
SupplyConfig = Annotated[Union[ScpiSupplyConfig], Field(discriminator="driver")]  # noqa: UP007
