"""The rig file: which devices to use, how thrust is read off the sensor, where runs are stored.

`open_rig` turns a validated Rig into live devices (a RigSet) for the engine.
"""

from __future__ import annotations

import functools
import operator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from rigtool.accuracy import SensorAccuracy
from rigtool.bounds import DepthM
from rigtool.clock import RealClock, VirtualClock
from rigtool.config import load_model, locate
from rigtool.devices.axes import rotation_deg, wrench_transform
from rigtool.devices.base import (
    Actuator,
    ActuatorInfo,
    Carriage,
    Clock,
    DepthStage,
    ForceSensor,
    Supply,
)
from rigtool.devices.dbc_can import DbcCanConfig, DbcMismatch
from rigtool.devices.depth import ManualDepth, PresetDepth
from rigtool.devices.manual_carriage import ManualCarriage
from rigtool.devices.manual_supply import ManualSupply
from rigtool.devices.registry import actuator_info, config_models, open_device
from rigtool.devices.visa_link import sim_file
from rigtool.errors import ConfigError, UsageError
from rigtool.protocol import CaptiveAxis, SimulatorSpec
from rigtool.thruster_profiles import profile_with_overrides
from rigtool.units import FT_CHANNELS


def _section(role: str) -> Any:
    """A device section: the config model of the driver its `driver:` field names, one of those
    devices/registry.py lists for `role` (the registry is the one list)."""
    return Annotated[functools.reduce(operator.or_, config_models(role)),
                     Field(discriminator="driver")]


ActuatorConfig = _section("actuator")
SensorConfig = _section("sensor")
StageConfig = _section("depth_stage")
SupplyConfig = _section("supply")
CarriageConfig = _section("carriage")


class ThrustAxis(BaseModel):
    """Which F/T channel carries the thruster's axial force, and its sign (forward positive)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    channel: Literal["fx", "fy", "fz", "tx", "ty", "tz"] = "fx"
    sign: Literal[1, -1] = 1


class Mount(BaseModel):
    """How a six-axis sensor is mounted: rotation into thruster axes and the propeller centre."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    rotation_axis: Literal["x", "y", "z"] = "z"
    rotation_deg: Annotated[float, Field(ge=-360, le=360)] = 0.0
    offset_m: tuple[DepthM, DepthM, DepthM] = (0.0, 0.0, 0.0)  # propeller centre from the sensor

    def matrix(self) -> np.ndarray:
        return wrench_transform(rotation_deg(self.rotation_axis, self.rotation_deg), self.offset_m)


class Rig(BaseModel):
    """A whole rig file: the simulator, or an actuator + force sensor (+ depth stage, supply)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    rigtool_rig: Literal[1] = 1
    name: str = Field(min_length=1)
    description: str = ""
    db: str | None = None
    simulator: SimulatorSpec | None = None
    real_time: bool = False
    actuator: ActuatorConfig | None = None
    sensor: SensorConfig | None = None
    depth_stage: StageConfig | None = None
    supply: SupplyConfig | None = None
    carriage: CarriageConfig | None = None  # sets the flow or tow speed of captive runs
    thrust: ThrustAxis | None = None
    mount: Mount | None = None
    sensor_accuracy: SensorAccuracy | None = None

    @model_validator(mode="after")
    def _has_devices(self) -> Rig:
        hardware = self.actuator is not None or self.sensor is not None
        if self.simulator is not None and (hardware or self.depth_stage is not None
                                           or self.supply is not None or self.carriage is not None):
            raise ValueError("a rig is either the `simulator:` or hardware (`actuator:`, "
                             "`sensor:`, `depth_stage:`, `supply:`, `carriage:`), not both")
        if self.simulator is None and (self.actuator is None or self.sensor is None):
            raise ValueError("a hardware rig needs both an `actuator:` and a `sensor:` section "
                             "(or use a `simulator:` section)")
        if self.mount is not None and self.sensor is not None and self.sensor.axes < 6:
            raise ValueError("`mount:` transforms six-axis sensors; a single-axis gauge maps its "
                             "axis with its own `channel` and `sign`")
        return self


def load_rig(path: str | Path) -> tuple[Rig, dict]:
    """Read and validate a rig file; ConfigError names file, line and field.

    A relative `dbc:` path in the actuator section, and a relative instrument file of a
    supply's `visa_library: file.yaml@sim`, are taken relative to the rig file. A dbc-can
    mapping is checked against its DBC here, so a mismatch names its line.
    """
    rig, data = load_model(Path(path), Rig)
    sim_yaml = sim_file(getattr(rig.supply, "visa_library", None) or "")
    if sim_yaml and not Path(sim_yaml).is_absolute():
        supply = rig.supply.model_copy(
            update={"visa_library": f"{Path(path).parent / sim_yaml}@sim"})
        rig = rig.model_copy(update={"supply": supply})
    dbc = getattr(rig.actuator, "dbc", None)
    if dbc and not Path(dbc).is_absolute():
        actuator = rig.actuator.model_copy(update={"dbc": str(Path(path).parent / dbc)})
        rig = rig.model_copy(update={"actuator": actuator})
    if isinstance(rig.actuator, DbcCanConfig):
        try:
            actuator_info(rig.actuator)
        except DbcMismatch as exc:
            loc = ("actuator", *exc.loc)
            raise ConfigError([f"{locate(Path(path), loc)}: {'.'.join(loc)}: {exc}"]) from None
        except UsageError as exc:  # e.g. a neutral outside the command range
            raise ConfigError([f"{locate(Path(path), ('actuator',))}: actuator: {exc}"]) from None
    return rig, data


def sim_rig(spec: SimulatorSpec) -> Rig:
    """The rig used by `--sim`: the protocol's simulator profile on a virtual clock."""
    return Rig(name=f"simulator:{spec.profile}", simulator=spec)


@dataclass
class RigSet:
    """Open devices of one rig, ready for the engine."""

    actuator: Actuator
    sensor: ForceSensor
    depth_stage: DepthStage
    clock: Clock
    thrust_channel: int
    thrust_sign: int
    description: dict = field(default_factory=dict)
    world: object | None = None  # the simulator's shared state, when simulated
    transform: np.ndarray | None = None  # 6x6 wrench transform of a mounted sensor
    supply: Supply | None = None  # sets the supply voltage, when the protocol sweeps it
    sensor_rate_hz: float | None = None  # the sensor's own rate; None: it samples as asked
    sensor_rate_note: str | None = None  # why that rate is not the one the sensor states
    carriage: Carriage | None = None  # sets the flow of a captive run

    def annotations(self) -> list[dict]:
        """Ground-truth events a simulator knows (e.g. ventilation), to store with the run."""
        twin = getattr(self.world, "twin", None)
        if twin is None:
            return []
        return [{"kind": "sim.ventilation", "t_s": ev.t_start_s,
                 "detail": {"t_start_s": ev.t_start_s, "t_end_s": ev.t_end_s,
                            "drop_frac": ev.drop_frac, "depth_m": ev.depth_m,
                            "speed_rpm": ev.speed_rpm}}
                for ev in twin.events]

    def counters(self) -> dict[str, dict[str, int]]:
        """Transport counters (frames, garbage, lost packets...) of the devices that keep them."""
        out = {}
        for role, dev in (("actuator", self.actuator), ("sensor", self.sensor),
                          ("depth_stage", self.depth_stage), ("supply", self.supply),
                          ("carriage", self.carriage)):
            gauges = getattr(dev, "stats_gauges", ())
            kept = {k: v for k, v in (getattr(dev, "stats", None) or {}).items()
                    if type(v) is int and k not in gauges}
            if kept:
                out[role] = kept
        return out

    def close(self) -> None:
        """Close every device, the actuator and carriage first; a failure is raised after all
        are closed."""
        errors = []
        for dev in (self.actuator, self.carriage, self.sensor, self.depth_stage, self.supply):
            if dev is None:
                continue
            try:
                dev.close()
            except Exception as exc:  # noqa: BLE001 - close the rest, then raise the first
                errors.append(exc)
        if errors:
            raise errors[0]


def counter_delta(before: dict[str, dict[str, int]],
                  after: dict[str, dict[str, int]]) -> dict[str, dict[str, int]]:
    """What each transport counter added between two `RigSet.counters()` readings."""
    return {role: {k: v - before.get(role, {}).get(k, 0) for k, v in counters.items()}
            for role, counters in after.items()}


def open_rig(rig: Rig, start_depth_m: float, depth_mode: str = "preset",
             voltage_mode: str | None = None, current_limit_a: float | None = None,
             captive: CaptiveAxis | None = None) -> RigSet:
    """Open the devices a rig names; a device that cannot be opened raises DeviceError.

    A supply is opened only when the protocol sweeps voltage (`voltage_mode`), its current
    limit set from the protocol's `max_current_a` when given; a carriage only for a captive run.
    """
    if rig.simulator is not None:
        rigset = _open_sim(rig, rig.simulator, start_depth_m)
        if voltage_mode is not None:
            from rigtool.sim.devices import SimSupply
            rigset.supply = SimSupply(rigset.world) if voltage_mode == "preset" else ManualSupply()
        if captive is not None:
            rigset.carriage = _sim_carriage(rigset, rig.simulator, captive)
        return rigset
    opened: list = []
    try:
        actuator: Actuator = open_device("actuator", rig.actuator)
        opened.append(actuator)
        sensor: ForceSensor = open_device("sensor", rig.sensor)
        opened.append(sensor)
        if rig.depth_stage is not None:
            stage: DepthStage = open_device("depth_stage", rig.depth_stage)
        elif depth_mode == "stage":
            raise UsageError(f"rig {rig.name!r}: the protocol asks for a depth stage, "
                             "but the rig has no `depth_stage:` section")
        elif depth_mode == "manual":
            stage = ManualDepth()
        else:
            stage = PresetDepth()
        supply = _open_supply(rig, voltage_mode, current_limit_a)
        opened.append(supply)
        carriage = _open_carriage(rig, captive)
    except BaseException:
        for dev in reversed(opened):
            if dev is not None:
                dev.close()
        raise
    axis = rig.thrust or ThrustAxis()
    return RigSet(
        actuator=actuator, sensor=sensor, depth_stage=stage, clock=RealClock(),
        thrust_channel=FT_CHANNELS.index(axis.channel), thrust_sign=axis.sign,
        description={"kind": "hardware", "actuator": rig.actuator.driver,
                     "sensor": rig.sensor.driver, "thrust": axis.model_dump()},
        transform=rig.mount.matrix() if rig.mount else None, supply=supply, carriage=carriage,
    )


def rig_actuator_info(rig: Rig) -> ActuatorInfo:
    """The actuator's command space from the rig file (or the twin's profile) alone."""
    if rig.simulator is not None:
        p = profile_with_overrides(rig.simulator.profile, dict(rig.simulator.overrides))
        return ActuatorInfo(p.command_unit, p.neutral, p.command_min, p.command_max,
                            tuple(p.feedback))
    return actuator_info(rig.actuator)


def _open_supply(rig: Rig, voltage_mode: str | None,
                 current_limit_a: float | None) -> Supply | None:
    """The supply a voltage sweep needs: the rig's programmable one, or the operator."""
    if voltage_mode is None:
        return None
    if voltage_mode == "manual":
        return ManualSupply()
    if rig.supply is None:
        raise UsageError(f"rig {rig.name!r}: the protocol sets supply voltages (`voltage: "
                         "{mode: preset}`), but the rig has no `supply:` section")
    config = rig.supply
    if current_limit_a is not None:
        config = config.model_copy(update={"current_limit_a": current_limit_a})
    return open_device("supply", config)


def _open_carriage(rig: Rig, captive: CaptiveAxis | None) -> Carriage | None:
    """The carriage a captive run needs: the rig's, or the operator."""
    if captive is None:
        return None
    if captive.mode == "manual":
        return ManualCarriage()
    if rig.carriage is None:
        raise UsageError(f"rig {rig.name!r}: the protocol runs a captive test (`captive: "
                         "{mode: preset}`), but the rig has no `carriage:` section")
    return open_device("carriage", rig.carriage)


def _sim_carriage(rigset: RigSet, spec: SimulatorSpec, captive: CaptiveAxis) -> Carriage:
    """The twin's carriage holding the simulator's vehicle in its flow (or the operator)."""
    if captive.mode == "manual":
        return ManualCarriage()
    from rigtool.sim.devices import SimCarriage
    from rigtool.sim.flow import VEHICLES, CaptiveFlow

    flow = CaptiveFlow(VEHICLES[spec.vehicle], angle=captive.angle,
                       noise_frac=spec.flow_noise_frac, seed=spec.seed,
                       t0=rigset.clock.now())
    rigset.description.update({"vehicle": spec.vehicle, "flow_noise_frac": spec.flow_noise_frac})
    return SimCarriage(rigset.world, flow)


def _open_sim(rig: Rig, spec: SimulatorSpec, start_depth_m: float) -> RigSet:
    """The in-process twin: a simulated operator sets every depth, time is virtual unless real_time."""
    from rigtool.sim.devices import SimActuator, SimDepthStage, SimForceSensor, SimWorld
    from rigtool.sim.physics import ThrusterTwin

    profile = profile_with_overrides(spec.profile, dict(spec.overrides))
    clock: Clock = RealClock() if rig.real_time else VirtualClock()
    twin = ThrusterTwin(profile, seed=spec.seed, depth_m=start_depth_m, t0=clock.now())
    world = SimWorld(twin, clock)
    axis = rig.thrust or ThrustAxis(channel=FT_CHANNELS[profile.thrust_channel],
                                    sign=profile.thrust_sign)
    return RigSet(
        actuator=SimActuator(world), sensor=SimForceSensor(world), depth_stage=SimDepthStage(world),
        clock=clock, thrust_channel=FT_CHANNELS.index(axis.channel), thrust_sign=axis.sign,
        description={"kind": "simulator", "profile": profile.name, "seed": spec.seed,
                     "overrides": dict(spec.overrides), "thrust": axis.model_dump()},
        world=world, transform=rig.mount.matrix() if rig.mount else None,
    )
