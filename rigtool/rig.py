"""The rig file: which devices to use, how thrust is read off the sensor, where runs are stored.

`open_rig` turns a validated Rig into live devices (a RigSet) for the engine.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from rigtool.clock import RealClock, VirtualClock
from rigtool.config import load_model
from rigtool.devices.base import FT_CHANNELS, Actuator, Clock, DepthStage, ForceSensor
from rigtool.errors import UsageError
from rigtool.protocol import SimulatorSpec


class ThrustAxis(BaseModel):
    """Which F/T channel carries the thruster's axial force, and its sign (forward positive)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    channel: Literal["fx", "fy", "fz", "tx", "ty", "tz"] = "fx"
    sign: Literal[1, -1] = 1


class Rig(BaseModel):
    """A whole rig file."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    rigtool_rig: Literal[1] = 1
    name: str = Field(min_length=1)
    description: str = ""
    db: str | None = None
    simulator: SimulatorSpec | None = None
    real_time: bool = False
    thrust: ThrustAxis | None = None

    @model_validator(mode="after")
    def _has_devices(self) -> Rig:
        if self.simulator is None:
            raise ValueError(
                "this rig names no devices: add a `simulator:` section "
                "(hardware drivers are configured with the drivers of a later release)")
        return self


def load_rig(path: str | Path) -> tuple[Rig, dict]:
    """Read and validate a rig file; ConfigError names file, line and field."""
    return load_model(Path(path), Rig)


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

    def close(self) -> None:
        for dev in (self.actuator, self.sensor, self.depth_stage):
            dev.close()


def open_rig(rig: Rig, start_depth_m: float) -> RigSet:
    """Open the devices a rig names. On the simulator a simulated operator sets every depth."""
    from rigtool.sim.devices import SimActuator, SimDepthStage, SimForceSensor, SimWorld
    from rigtool.sim.physics import ThrusterTwin
    from rigtool.sim.profiles import profile_with_overrides

    spec = rig.simulator
    if spec is None:
        raise UsageError(f"rig {rig.name!r} names no devices")
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
        world=world,
    )
