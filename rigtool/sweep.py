"""Set up a sweep: resolve protocol and rig, check them against each other, run the engine."""

from __future__ import annotations

import socket
from dataclasses import dataclass
from pathlib import Path

from rigtool import __version__
from rigtool.engine import Engine, Outcome
from rigtool.errors import ConfigError, UsageError
from rigtool.plan import PlanStep, expand
from rigtool.protocol import Protocol, load_protocol
from rigtool.rig import Rig, RigSet, load_rig, open_rig, sim_rig
from rigtool.store import Store


@dataclass
class SweepSetup:
    """Everything a sweep needs, resolved and checked before any device moves."""

    protocol: Protocol
    protocol_path: Path
    rig: Rig
    plan: list[PlanStep]


def resolve(protocol_path: str | Path, rig_path: str | None = None, sim: bool = False,
            seed: int | None = None) -> SweepSetup:
    """Load the protocol, choose the rig (--rig, --sim, or the protocol's `rig:`), expand the plan."""
    path = Path(protocol_path)
    protocol, _ = load_protocol(path)
    if rig_path:
        rig, _ = load_rig(rig_path)
    elif sim:
        if protocol.simulator is None:
            raise ConfigError([f"{path}: --sim needs a `simulator:` section naming a profile "
                               "(e.g. `simulator: {profile: can-bldc}`)"])
        rig = sim_rig(protocol.simulator)
    elif protocol.rig:
        rig, _ = load_rig(path.parent / protocol.rig)
    else:
        raise UsageError(f"{path}: no rig given: pass --rig RIG.yaml, or --sim for the simulator")
    if seed is not None and rig.simulator is not None:
        rig = rig.model_copy(update={"simulator": rig.simulator.model_copy(update={"seed": seed})})
    return SweepSetup(protocol, path, rig, expand(protocol))


def check_compatible(setup: SweepSetup, rigset: RigSet) -> None:
    """The protocol's commands must be in the actuator's unit and range."""
    info = rigset.actuator.info
    cmd = setup.protocol.command
    problems = []
    if cmd.unit != info.command_unit:
        problems.append(f"{setup.protocol_path}: command.unit: the rig's actuator takes "
                        f"{info.command_unit}, the protocol sweeps {cmd.unit}")
    values = cmd.command_values()
    lo, hi = min(values), max(values)
    if lo < info.command_min or hi > info.command_max:
        problems.append(f"{setup.protocol_path}: command: values {lo:g}..{hi:g} leave the "
                        f"actuator's range {info.command_min:g}..{info.command_max:g} {info.command_unit}")
    if problems:
        raise ConfigError(problems)


def open_checked(setup: SweepSetup) -> RigSet:
    """Open the rig's devices and check the protocol against them (closing them on failure)."""
    rigset = open_rig(setup.rig, start_depth_m=setup.plan[0].depth_m)
    try:
        check_compatible(setup, rigset)
    except BaseException:
        rigset.close()
        raise
    return rigset


def run_sweep(setup: SweepSetup, store: Store, reporter=None) -> Outcome:
    """Create the run in the store and execute the plan on the rig."""
    rigset = open_checked(setup)
    try:
        sim = setup.rig.simulator
        run_id = store.create_run(
            name=setup.protocol.name,
            protocol=setup.protocol.model_dump(mode="json"),
            protocol_path=str(setup.protocol_path),
            rig={**setup.rig.model_dump(mode="json"), "resolved": rigset.description,
                 "host": socket.gethostname()},
            plan=[s.as_dict() for s in setup.plan],
            metadata=setup.protocol.metadata.model_dump(mode="json"),
            seed=sim.seed if sim else None,
            command_unit=rigset.actuator.info.command_unit,
            tool_version=__version__,
        )
        engine = Engine(setup.protocol, setup.plan, rigset, store, run_id, reporter)
        return engine.run()
    finally:
        rigset.close()
