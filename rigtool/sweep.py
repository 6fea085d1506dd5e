"""Set up a sweep: resolve protocol and rig, check them against each other, run the engine."""

from __future__ import annotations

import contextlib
import dataclasses
import os
import signal
import socket
import sqlite3
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from pydantic import ValidationError

from rigtool.bounds import MAX_RUN_S, MAX_SEED
from rigtool.config import coerced_values, locate
from rigtool.dbpath import DB_ENV, resolve_db_path
from rigtool.devices.base import ActuatorInfo
from rigtool.engine import Engine, Outcome
from rigtool.errors import ConfigError, StoreError, UsageError
from rigtool.files import UnreadableFile
from rigtool.limit_sources import source_problems
from rigtool.plan import PlanStep, estimate_duration_s, expand, step_at
from rigtool.protocol import Protocol, load_protocol
from rigtool.rig import Rig, RigSet, load_rig, open_rig, rig_actuator_info, sim_rig
from rigtool.sensor_rate import check_sensor_rate
from rigtool.store import Store
from rigtool.version import __version__


@dataclass
class SweepSetup:
    """Everything a sweep needs, resolved and checked before any device moves.

    The plan is expanded on first use only, so `--dry-run` never builds it.
    """

    protocol: Protocol
    protocol_path: Path
    rig: Rig
    expanded: list[PlanStep] | None = None
    rig_path: Path | None = None  # the rig file, when the rig came from one

    @property
    def plan(self) -> list[PlanStep]:
        if self.expanded is None:
            self.expanded = expand(self.protocol)
        return self.expanded


def resolve(protocol_path: str | Path, rig_path: str | None = None, sim: bool = False,
            seed: int | None = None) -> SweepSetup:
    """Load the protocol, choose the rig (--rig, --sim, or the protocol's `rig:`), expand the plan."""
    path = Path(protocol_path)
    protocol, _ = load_protocol(path)
    if seed is not None and not 0 <= seed <= MAX_SEED:
        raise UsageError(f"--seed {seed}: a simulator seed is 0..{MAX_SEED}")
    rig_file = None
    if rig_path:
        rig_file = Path(rig_path)
        rig, _ = load_rig(rig_file)
    elif sim:
        if protocol.simulator is None:
            raise ConfigError([f"{locate(path, ())}: --sim needs a `simulator:` section naming a "
                               "profile (e.g. `simulator: {profile: can-bldc}`)"])
        rig = sim_rig(protocol.simulator)
    elif protocol.rig:
        rig_file = path.parent / protocol.rig
        try:
            rig, _ = load_rig(rig_file)
        except UnreadableFile as exc:
            raise ConfigError([f"{locate(path, ('rig',))}: rig: {exc.problem}: {rig_file}"]) from None
    else:
        raise ConfigError([f"{locate(path, ())}: no rig given: add `rig: RIG.yaml`, pass "
                           "--rig RIG.yaml, or --sim for the simulator"])
    if seed is not None and rig.simulator is not None:
        rig = rig.model_copy(update={"simulator": rig.simulator.model_copy(update={"seed": seed})})
    return SweepSetup(protocol, path, rig, rig_path=rig_file)


def open_store(cli_db: str | None, rig: Rig | None, rig_path: Path | None,
               create: bool = True) -> Store:
    """The run database; when the rig file's `db:` chose it, a path that cannot be a
    database is a config error naming that line."""
    path = resolve_db_path(cli_db, rig.db if rig else None)
    from_rig = rig is not None and rig.db and rig_path is not None and not (
        cli_db or os.environ.get(DB_ENV))
    try:
        return Store(path, create=create)
    except (UsageError, StoreError) as exc:
        cause = exc.__cause__
        about_path = isinstance(exc, UsageError) or isinstance(cause, OSError) or (
            isinstance(cause, sqlite3.DatabaseError)
            and any(k in str(cause) for k in ("unable to open", "not a database")))
        if not (from_rig and about_path):
            raise
        raise ConfigError([f"{locate(rig_path, ('db',))}: db: {exc}"]) from None


def check_compatible(setup: SweepSetup, info: ActuatorInfo) -> None:
    """The protocol's commands must be in the actuator's unit and range, and the run, ramps
    included, must fit MAX_RUN_S now that the actuator's neutral is known."""
    cmd = setup.protocol.command
    path = setup.protocol_path
    problems = []
    if cmd.unit != info.command_unit:
        problems.append(f"{locate(path, ('command', 'unit'))}: command.unit: the rig's actuator "
                        f"takes {info.command_unit}, the protocol sweeps {cmd.unit}")
    values = cmd.command_values()
    lo, hi = min(values), max(values)
    if lo < info.command_min or hi > info.command_max:
        source = "values" if cmd.values is not None else "range"
        problems.append(f"{locate(path, ('command', source))}: command.{source}: values "
                        f"{lo:g}..{hi:g} leave the actuator's range {info.command_min:g}.."
                        f"{info.command_max:g} {info.command_unit}")
    problems += source_problems(setup.protocol, path, setup.rig, info)
    duration = estimate_duration_s(setup.protocol, info.neutral)
    if not problems and duration > MAX_RUN_S:
        problems.append(f"{locate(path, ('limits', 'slew_per_s'))}: limits.slew_per_s: the run "
                        f"would take {duration / 86_400:,.3g} days with its ramps from neutral "
                        f"{info.neutral:g} {info.command_unit}; the limit is {MAX_RUN_S / 86_400:g} days")
    if problems:
        raise ConfigError(problems)


def check_depth_source(setup: SweepSetup) -> None:
    """Depths are set by a stage, the simulator or the operator; `preset` holds only one."""
    rig, depth = setup.rig, setup.protocol.depth
    if rig.simulator is not None or rig.depth_stage is not None or depth.mode == "manual":
        return
    where = locate(setup.protocol_path, ("depth", "mode"))
    if depth.mode == "stage":
        raise ConfigError([f"{where}: depth.mode: 'stage' needs a `depth_stage:` section in "
                           f"rig {rig.name!r}, which has none"])
    depths = sorted(set(depth.depths_m()))
    if len(depths) > 1:
        listed = ", ".join(f"{d:g}" for d in depths)
        raise ConfigError([
            f"{where}: depth.mode: 'preset' means one fixed depth, but the protocol asks for "
            f"{len(depths)} ({listed} m) and rig {rig.name!r} has no `depth_stage:` to set them; "
            "use `mode: manual` (the operator sets and confirms each depth) or add a depth stage"])


def check_supply(setup: SweepSetup) -> None:
    """A preset voltage sweep needs the rig's supply (or the simulator), within its rating."""
    rig, voltage = setup.rig, setup.protocol.voltage
    if voltage is None or voltage.mode == "manual" or rig.simulator is not None:
        return
    where = locate(setup.protocol_path, ("voltage", "mode"))
    if rig.supply is None:
        raise ConfigError([f"{where}: voltage.mode: 'preset' needs a `supply:` section in rig "
                           f"{rig.name!r}, which has none; add one, or use `mode: manual` (the "
                           "operator sets and confirms each voltage)"])
    top = max(voltage.values)
    if top > rig.supply.max_voltage_v:
        raise ConfigError([f"{locate(setup.protocol_path, ('voltage', 'values'))}: "
                           f"voltage.values: {top:g} V is above the supply's max_voltage_v "
                           f"({rig.supply.max_voltage_v:g} V) in rig {rig.name!r}"])


def check_carriage(setup: SweepSetup) -> None:
    """A preset captive run needs the rig's carriage (or the simulator), within its limits."""
    rig, captive = setup.rig, setup.protocol.captive
    if captive is None or captive.mode == "manual" or rig.simulator is not None:
        return
    if rig.carriage is None:
        raise ConfigError([f"{locate(setup.protocol_path, ('captive', 'mode'))}: captive.mode: "
                           f"'preset' needs a `carriage:` section in rig {rig.name!r}, which has "
                           "none (or use `mode: manual`: the operator sets each flow)"])
    cfg = rig.carriage
    fast = max(abs(v) for v in captive.speeds_mps)
    problems = []
    if fast > cfg.max_speed_mps:
        problems.append(f"{locate(setup.protocol_path, ('captive', 'speeds_mps'))}: "
                        f"captive.speeds_mps: {fast:g} m/s is beyond the carriage's "
                        f"max_speed_mps ({cfg.max_speed_mps:g} m/s) in rig {rig.name!r}")
    outside = [a for a in captive.angles_deg if not cfg.min_angle_deg <= a <= cfg.max_angle_deg]
    if outside:
        problems.append(f"{locate(setup.protocol_path, ('captive', 'angles_deg'))}: "
                        f"captive.angles_deg: {outside[0]:g} deg is outside the carriage's "
                        f"{cfg.min_angle_deg:g}..{cfg.max_angle_deg:g} deg in rig {rig.name!r}")
    if problems:
        raise ConfigError(problems)


def open_checked(setup: SweepSetup, start_idx: int = 0) -> RigSet:
    """Open the rig's devices and check the protocol against them (closing them on failure)."""
    check_depth_source(setup)
    check_supply(setup)
    check_carriage(setup)
    voltage = setup.protocol.voltage
    rigset = open_rig(setup.rig, start_depth_m=step_at(setup.protocol, start_idx).depth_m,
                      depth_mode=setup.protocol.depth.mode,
                      voltage_mode=voltage.mode if voltage else None,
                      current_limit_a=setup.protocol.limits.max_current_a,
                      captive=setup.protocol.captive)
    try:
        check_compatible(setup, rigset.actuator.info)
        check_sensor_rate(setup.protocol, setup.protocol_path, rigset)
    except BaseException:
        rigset.close()
        raise
    return rigset


def check_dry_run(setup: SweepSetup) -> ActuatorInfo:
    """Every check a sweep makes before it moves, from the files alone: a dry run opens,
    commands and changes no device. Returns the actuator's command space (its neutral)."""
    check_depth_source(setup)
    check_supply(setup)
    check_carriage(setup)
    info = rig_actuator_info(setup.rig)
    check_compatible(setup, info)
    return info


RESUMABLE = ("interrupted", "aborted", "failed")


def _rig_kind(rig: Rig) -> tuple:
    """What must not change between a run and its resume: twin profile, drivers, thrust axis, mount."""
    return (rig.simulator.profile if rig.simulator else None,
            getattr(rig.actuator, "driver", None), getattr(rig.sensor, "driver", None),
            getattr(rig.depth_stage, "driver", None), getattr(rig.supply, "driver", None),
            getattr(rig.carriage, "driver", None), rig.thrust, rig.mount)


def mark_interrupted(store: Store, run_ref: str) -> None:
    """`sweep --resume RUN --force`: a run still marked running (its process is known gone to
    the operator) is marked interrupted, so it resumes."""
    run_id = store.resolve_run_id(run_ref)
    if store.run(run_id)["status"] == "running":
        store.finish_run(run_id, "interrupted", "marked interrupted by --force")


def resolve_resume(store: Store, run_ref: str,
                   rig: Rig | None = None) -> tuple[str, SweepSetup, int, float]:
    """Rebuild the setup of a stored run; return (run id, setup, first unfinished step, run time used).

    `rig` replaces the stored rig (a port that moved after a power cut); it must have the same
    drivers, thrust axis and mount.
    """
    run_id = store.resolve_run_id(run_ref)
    run = store.run(run_id)
    _refuse_import(run_id, run)
    if run["status"] not in RESUMABLE:
        raise UsageError(f"run {run_id} is {run['status']}; only {', '.join(RESUMABLE)} runs resume")
    rig_data = {k: v for k, v in run["rig"].items() if k not in ("resolved", "host")}
    try:
        protocol = Protocol.model_validate(run["protocol"])
        stored = Rig.model_validate(rig_data)
    except ValidationError as exc:
        raise UsageError(f"run {run_id}: its stored protocol or rig no longer validates "
                         f"({exc.error_count()} problem(s), first: {exc.errors()[0]['msg']}); "
                         "cannot resume") from None
    coerced = [f"{what}.{'.'.join(map(str, loc))}"
               for what, data, model in (("protocol", run["protocol"], protocol),
                                         ("rig", rig_data, stored))
               for loc in coerced_values(data, model)]
    if coerced:
        raise UsageError(f"run {run_id}: its stored {', '.join(coerced[:5])} holds true/false "
                         "or text where a number or name belongs; cannot resume")
    if rig is not None and _rig_kind(rig) != _rig_kind(stored):
        raise UsageError(f"run {run_id} was recorded on rig {stored.name!r}; the rig given to "
                         "--resume must have the same drivers, thrust axis and mount (only "
                         "ports, addresses and the like may change)")
    rig = rig or stored
    plan = expand(protocol)
    if [s.as_dict() for s in plan] != run["plan"]:
        raise UsageError(f"run {run_id}: its stored plan no longer expands the same way; cannot resume")
    steps = store.steps(run_id)
    done = [s["idx"] for s in steps]
    if done != list(range(len(done))):
        raise UsageError(f"run {run_id}: stored points are not a prefix of the plan; cannot resume")
    t_used = max((s["t_end_s"] for s in steps), default=0.0)
    path = Path(run["protocol_path"] or "protocol")
    return run_id, SweepSetup(protocol, path, rig, plan), len(done), t_used


def _refuse_import(run_id: str, run: dict) -> None:
    """An imported run has no rig to drive and no plan to finish: say so instead of resuming."""
    resolved = run["rig"].get("resolved") if isinstance(run["rig"], dict) else None
    if not (isinstance(resolved, dict) and resolved.get("kind") == "import"):
        return
    if run["status"] == "completed":
        raise UsageError(f"run {run_id} is an imported run, not a sweep: it cannot be resumed")
    raise UsageError(f"run {run_id} is an incomplete import ({run['status']}: "
                     f"{run['stop_reason'] or 'no reason stored'}); an import cannot be resumed: "
                     "run `rigtool import` on the file again")


def terminal_confirm() -> Callable[[str], bool] | None:
    """A yes/no prompt on the terminal, or None when nobody is there to answer."""
    if not sys.stdin.isatty():
        return None
    return lambda question: input(f"{question} [y/N] ").strip().lower() in ("y", "yes")


def resume_sweep(store: Store, run_ref: str, reporter=None,
                 confirm: Callable[[str], bool] | None = None,
                 rig: Rig | None = None) -> tuple[Outcome, int]:
    """Continue a stopped run from its first unfinished point, in the same run id."""
    run_id, setup, start_idx, t_used = resolve_resume(store, run_ref, rig)
    previous = store.run(run_id)["status"]
    if start_idx >= len(setup.plan):
        store.reopen_run(run_id)  # claimed like any resume, and it becomes `last`
        store.finish_run(run_id, "completed", None)
        return Outcome(run_id, "completed", None, 0), len(setup.plan)
    rigset = open_checked(setup, start_idx)
    try:
        store.reopen_run(run_id)
        detail = {"from_idx": start_idx, "previous_status": previous}
        if rig is not None:
            detail["rig"] = setup.rig.model_dump(mode="json")
        store.add_event(run_id, "resumed", detail, t_s=t_used)
        engine = Engine(setup.protocol, setup.plan, rigset, store, run_id, reporter, confirm)
        return engine.run(start_idx, t_offset_s=t_used + 1.0), len(setup.plan)
    finally:
        rigset.close()


def run_sweep(setup: SweepSetup, store: Store, reporter=None,
              confirm: Callable[[str], bool] | None = None) -> Outcome:
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
            actuator=dataclasses.asdict(rigset.actuator.info),
        )
        try:
            engine = Engine(setup.protocol, setup.plan, rigset, store, run_id, reporter, confirm)
            return engine.run()
        except BaseException as exc:  # before the engine took the run over: close it here
            _close_unstarted(store, run_id, exc)
            raise
    finally:
        rigset.close()


def _close_unstarted(store: Store, run_id: str, exc: BaseException) -> None:
    """Record how a run ended that a signal or an error stopped before the engine's own
    handling began (it would stay `running`); the devices close with neutral after this. A
    store that fails here leaves the first error to be reported."""
    with contextlib.suppress(Exception):
        if store.run(run_id)["status"] != "running":
            return
        if isinstance(exc, KeyboardInterrupt):
            name = getattr(exc, "signum", None)
            why = f"stopped by {signal.Signals(name).name}" if name else "stopped by the operator"
            store.finish_run(run_id, "aborted", f"{why} before the first point")
        else:
            store.finish_run(run_id, "failed", f"{type(exc).__name__} before the first point")
