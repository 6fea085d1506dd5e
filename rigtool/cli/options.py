"""Options several commands share, as argparse parent parsers (`parents=`): the run database,
the run, the output folder; and the argument types they check."""

from __future__ import annotations

import argparse
import re

from rigtool.dbpath import DB_ENV

DB_HELP = f"run database (default: ${DB_ENV}, the rig file's db, or ./rigtool.sqlite)"
RUN_HELP = "run id, unique prefix, or `last`"


def _parent() -> argparse.ArgumentParser:
    return argparse.ArgumentParser(add_help=False)


def out_folder(default: str, help: str) -> argparse.ArgumentParser:
    """`--out`: the folder a command writes its files in."""
    parent = _parent()
    parent.add_argument("--out", default=default, help=help)
    return parent


DB = _parent()
DB.add_argument("--db", help=DB_HELP)

RUN = _parent()
RUN.add_argument("run", help=RUN_HELP)

CALIBRATIONS_OUT = out_folder("calibrations", "output folder (default: ./calibrations)")


def port_number(text: str) -> int:
    """A TCP port, 0 for any free one."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r} is not a port (0 .. 65535; 0: any free port)")
    return value


def positive_int(text: str) -> int:
    """A whole number from 1."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number from 1")
    return value


NAMESPACE = re.compile(r"/?[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*")


def namespace(text: str) -> str:
    """A ROS 2 / gz topic namespace: names of letters, digits and _ (not led by a digit),
    joined by /, a leading / allowed; anything else would be escaped into a name no node
    publishes under."""
    if NAMESPACE.fullmatch(text) is None:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a namespace: names of letters, digits and _ (none starting with "
            "a digit) joined by /")
    return text
