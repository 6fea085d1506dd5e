"""`rigtool check`: open a rig's devices, read for a few seconds, print rates and noise."""

from __future__ import annotations

import argparse

from rich.table import Table

from rigtool.cli.console import out
from rigtool.cli.signals import stop_on_signals
from rigtool.errors import UsageError


def add_parsers(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("check", help="open a rig's devices, read for a few seconds, print rates and noise")
    p.add_argument("rig", help="rig YAML file")
    p.add_argument("--seconds", type=float, default=3.0)
    p.add_argument("--rate", type=float, default=1000.0, help="requested sample rate (Hz)")
    p.add_argument("--command", type=float, help="test command to hold while reading (default: neutral only)")
    p.set_defaults(func=cmd_check)


def cmd_check(args: argparse.Namespace) -> int:
    from rigtool.check import run_check, supply_lines
    from rigtool.rig import load_rig, open_rig

    if args.rate <= 0 or args.seconds <= 0:
        raise UsageError("--rate and --seconds must be positive")
    rig, _ = load_rig(args.rig)
    rigset = open_rig(rig, start_depth_m=1.0)
    try:
        info = rigset.actuator.info
        if args.command is not None and not info.command_min <= args.command <= info.command_max:
            raise UsageError(f"--command {args.command:g} is outside the actuator's range "
                             f"{info.command_min:g}..{info.command_max:g} {info.command_unit}")
        with stop_on_signals():
            report = run_check(rigset, args.seconds, args.rate, args.command)
    finally:
        rigset.close()
    out.print(f"rig {rig.name!r}: {report.samples} force samples in {report.seconds:.2f} s "
              f"({report.rate_hz:.1f} Hz); feedback at {report.feedback_rate_hz:.1f} Hz")
    table = Table("channel", "unit", "n", "mean", "noise (std)")
    for c in report.channels + report.feedback:
        table.add_row(c.name, c.unit, str(c.n), f"{c.mean:.4g}", f"{c.std:.3g}")
    out.print(table)
    for role, counters in report.counters.items():
        out.print(f"  {role}: " + ", ".join(f"{k}={v}" for k, v in counters.items()))
    if rig.supply is not None:
        for line in supply_lines(rig.supply):
            out.print(line)
    return 0
