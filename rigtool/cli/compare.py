"""`rigtool compare`: compare thrusters (runs); write corrections and a report."""

from __future__ import annotations

import argparse

from rich.table import Table

from rigtool.cli.console import err, out
from rigtool.cli.options import DB, out_folder
from rigtool.dbpath import resolve_db_path
from rigtool.store import Store


def add_parsers(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("compare", help="compare thrusters (runs); write corrections and a report",
                       parents=[out_folder("calibrations/compare", "output folder"), DB])
    p.add_argument("runs", nargs="+", metavar="RUN", help="run ids, unique prefixes, or `last`")
    p.add_argument("--reference", metavar="RUN", help="match this run (default: the mean of the runs)")
    p.add_argument("--floor-frac", type=float, default=0.1,
                   help="ignore thrust below this fraction of the shared maximum (default 0.1)")
    p.set_defaults(func=cmd_compare)


def cmd_compare(args: argparse.Namespace) -> int:
    from rigtool import workflows

    with Store(resolve_db_path(args.db), read_only=True) as store:
        result, paths = workflows.compare(store, args.runs, args.reference, args.out,
                                          floor_frac=args.floor_frac)
    table = Table("run", "thruster", "branch", "a", "b (" + result.command_unit + ")",
                  "max dev before", "max dev after", title=f"corrections vs {result.reference_label}")
    for c in result.corrections:
        table.add_row(c.run_id, c.label, c.branch, f"{c.a:.5g}", f"{c.b:.5g}",
                      f"{100 * c.max_dev_before:.2f} %", f"{100 * c.max_dev_after:.2f} %")
    out.print(table)
    for warning in result.warnings:
        err.print(f"warning: {warning}")
    out.print(f"spread between thrusters: {100 * result.spread_before:.2f} % before, "
              f"{100 * result.spread_after:.2f} % after correction")
    out.print("written: " + ", ".join(str(p) for p in paths))
    return 0
