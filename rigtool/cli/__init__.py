"""Command line: parses arguments, calls the application layer, prints. One module per command
(or small group), each with its parser beside its handler; the exit status is the outcome's."""

from __future__ import annotations

import argparse
import signal
from collections.abc import Sequence

from rigtool.cli import (
    calibrate,
    check,
    compare,
    export,
    importing,
    merge,
    runs,
    sim,
    sweep,
    vehicle,
    watch,
)
from rigtool.cli.console import err
from rigtool.errors import EXIT_FAILED, RigtoolError
from rigtool.stopping import ending
from rigtool.version import __version__

# In the order `rigtool --help` lists them.
COMMANDS = (sweep, watch, runs, calibrate, check, sim, export, merge, importing, compare, vehicle)


def build_parser() -> argparse.ArgumentParser:
    """The `rigtool` parser: each command module adds its own subcommand(s)."""
    parser = argparse.ArgumentParser(
        prog="rigtool", description="Sweep, calibrate and report on underwater thrusters.")
    parser.add_argument("--version", action="version", version=f"rigtool {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for command in COMMANDS:
        command.add_parsers(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `rigtool` console script."""
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except RigtoolError as exc:
        err.print(f"rigtool: error: {exc}")
        return exc.exit_status
    except OSError as exc:  # a path or port the user gave that the system refuses
        err.print(f"rigtool: error: {exc}")
        return EXIT_FAILED
    except KeyboardInterrupt as exc:
        line, status = ending(getattr(exc, "signum", signal.SIGINT))
        err.print(line)
        return status
