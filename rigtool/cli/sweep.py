"""`rigtool sweep`: run a protocol on a rig, or resume a stopped run; print how it ended and
exit with the status its outcome carries."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from rich.table import Table
from rich.text import Text

from rigtool.cli.console import err, out
from rigtool.cli.options import DB, port_number
from rigtool.cli.signals import closing_signals
from rigtool.cli.watch import watching
from rigtool.errors import UsageError
from rigtool.progress import default_reporter
from rigtool.store import Store
from rigtool.units import unit_label

if TYPE_CHECKING:
    from rigtool.engine import Outcome
    from rigtool.sweep import SweepSetup


def add_parsers(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sweep", help="run a protocol on a rig and store the run", parents=[DB])
    p.add_argument("protocol", nargs="?", help="protocol YAML file")
    p.add_argument("--resume", metavar="RUN_ID", help="continue a stopped run from its first unfinished point")
    p.add_argument("--force", action="store_true",
                   help="with --resume: take over a run still marked running (its process is gone "
                        "but was on another host, or its pid was reused)")
    p.add_argument("--rig", help="rig YAML file (overrides the protocol's `rig:`)")
    p.add_argument("--sim", action="store_true", help="run on the built-in simulator twin")
    p.add_argument("--seed", type=int, help="simulator seed (overrides the protocol's)")
    p.add_argument("--dry-run", action="store_true", help="print the plan and estimated duration only")
    p.add_argument("--watch", nargs="?", type=port_number, const=8765, metavar="PORT",
                   help="also serve the read-only watch page of the run (default port 8765; "
                        "docs/watch.md)")
    p.add_argument("--bind", default="127.0.0.1", metavar="ADDRESS",
                   help="with --watch: address to serve on (default 127.0.0.1: this host only)")
    p.set_defaults(func=cmd_sweep)


def cmd_sweep(args: argparse.Namespace) -> int:
    from rigtool.sweep import (
        check_dry_run,
        mark_interrupted,
        open_store,
        resolve,
        resume_sweep,
        run_sweep,
        terminal_confirm,
    )

    if args.resume:
        if args.protocol or args.sim or args.dry_run or args.seed is not None:
            raise UsageError("--resume RUN_ID takes the protocol and seed stored with the run; "
                             "give no protocol, --sim, --seed or --dry-run (--rig RIG.yaml may "
                             "replace the stored rig when a port or address changed)")
        from rigtool.rig import load_rig

        rig = load_rig(args.rig)[0] if args.rig else None
        store = open_store(args.db, rig, Path(args.rig) if args.rig else None, create=False)
        try:
            if args.force:
                mark_interrupted(store, args.resume)
            reporter = default_reporter()
            with closing_signals(reporter), watching(args.watch, store.path, args.bind):
                outcome, n_plan = resume_sweep(store, args.resume, reporter,
                                               terminal_confirm(), rig)
                return _report_outcome(outcome, n_plan, store)
        finally:
            store.close()
    if not args.protocol:
        raise UsageError("give a protocol file (or --resume RUN_ID)")
    setup = resolve(args.protocol, args.rig, args.sim, args.seed)
    if args.dry_run:
        _print_plan(setup, check_dry_run(setup).neutral)
        return 0
    store = open_store(args.db, setup.rig, setup.rig_path)
    try:
        reporter = default_reporter()
        with closing_signals(reporter), watching(args.watch, store.path, args.bind):
            outcome = run_sweep(setup, store, reporter, terminal_confirm())
            return _report_outcome(outcome, setup.protocol.n_points(), store)
    finally:
        store.close()


def _report_outcome(outcome: Outcome, n_plan: int, store: Store) -> int:
    """Print how the run ended; return the exit status its outcome carries."""
    steps = f"{len(store.steps(outcome.run_id))}/{n_plan} points"
    if outcome.status == "completed" and outcome.neutral_ok:
        out.print(f"run {outcome.run_id} completed: {steps} stored in {store.path}")
    elif not outcome.neutral_ok:
        why = f": {outcome.reason}" if outcome.reason else ""
        err.print(f"run {outcome.run_id} {outcome.status}{why}; {steps} kept in {store.path}. "
                  f"ERROR: {outcome.neutral_note}: check the thruster and cut its power.")
    else:
        err.print(f"run {outcome.run_id} {outcome.status}: {outcome.reason}; {steps} kept in "
                  f"{store.path}; actuator at neutral. Continue with: "
                  f"rigtool sweep --resume {outcome.run_id} --db {store.path}")
    return outcome.exit_status


def _fmt_duration(seconds: float) -> str:
    h, rem = divmod(int(round(seconds)), 3600)
    m, s = divmod(rem, 60)
    return f"{h} h {m:02d} min" if h else f"{m} min {s:02d} s"


def _print_plan(setup: SweepSetup, neutral: float) -> None:
    """The plan's size, timing and first and last steps, all counted without expanding it."""
    from rigtool.plan import estimate_duration_s, step_at
    from rigtool.sensor_rate import dry_run_rate

    p = setup.protocol
    n = p.n_points()
    unit = unit_label(p.command.unit)
    depths = sorted(set(p.depth.depths_m()))
    timing = p.timing
    out.print(Text.assemble((p.name, "bold"), f": {n} points on rig {setup.rig.name!r}"))
    out.print(f"  commands: {p.command.n_values()} values in {unit}, order "
              f"{p.command.order}, {p.command.repeats} repeat(s)")
    out.print(f"  depths: {', '.join(f'{d:g} m' for d in depths)} ({p.depth.mode}, loop {p.depth.loop})")
    if p.voltage is not None:
        out.print(f"  supply voltages: {', '.join(f'{v:g} V' for v in p.voltage.voltages_v())} "
                  f"({p.voltage.mode}, each held within {p.voltage.tolerance_frac:.0%})")
    if p.captive is not None:
        c = p.captive
        out.print(f"  captive flow: {', '.join(f'{v:g}' for v in c.speeds_mps)} m/s at "
                  f"{c.angle} {', '.join(f'{a:g}' for a in c.angles_deg)} deg ({c.mode}, "
                  f"settle {c.settle_s:g} s; the carriage stops on every exit)")
    out.print(f"  per point: settle {timing.settle.max_seconds():g} s max, acquire "
              f"{timing.acquire.n_samples} samples at {timing.acquire.rate_hz:g} Hz, rest {timing.rest_s:g} s; "
              f"tare {timing.tare}")
    out.print(f"  sensor timing: {dry_run_rate(p, setup.rig)}")
    out.print(f"  samples to store: {n * timing.acquire.n_samples:,}")
    out.print(f"  estimated duration on the rig: {_fmt_duration(estimate_duration_s(p, neutral))}")
    volts = p.voltage is not None
    table = Table("step", "command", "depth (m)", *(["supply (V)"] if volts else []), "repeat",
                  "direction")
    shown = list(range(n)) if n <= 6 else [0, 1, 2, n - 3, n - 2, n - 1]
    for i, idx in enumerate(shown):
        if n > 6 and i == 3:
            table.add_row("...", *[""] * (len(table.columns) - 1))
        s = step_at(p, idx)
        table.add_row(str(s.idx), f"{s.command:g} {unit}", f"{s.depth_m:g}",
                      *([f"{s.voltage_v:g}"] if volts else []), str(s.repeat), s.direction)
    out.print(table)
