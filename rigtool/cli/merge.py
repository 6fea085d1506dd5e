"""`rigtool merge`: merge the run databases of several rigs into one."""

from __future__ import annotations

import argparse
from pathlib import Path

from rigtool.cli.console import err, out
from rigtool.errors import DataError, UsageError
from rigtool.progress import stage
from rigtool.store import Store


def add_parsers(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("merge", help="merge the run databases of several rigs into one")
    p.add_argument("stores", nargs="+", metavar="DB", help="run databases to merge")
    p.add_argument("-o", "--output", required=True, metavar="DB",
                   help="merged database (created, or added to; runs already there are skipped)")
    p.set_defaults(func=cmd_merge)


def cmd_merge(args: argparse.Namespace) -> int:
    target = Path(args.output)
    sources = [Path(s) for s in args.stores]
    for src in sources:
        if not src.is_file():
            raise UsageError(f"no run database at {src}")
        if target.exists() and src.resolve() == target.resolve():
            raise UsageError(f"{src} is the output: give another -o")
    created = not target.exists()
    try:
        with (Store(target) as store,
              stage(f"merging {len(sources)} database(s) into {target}") as progress):
            reports = store.merge_from(sources, progress)
    except (DataError, UsageError) as exc:
        if created:  # a refused merge leaves no empty database where there was none
            for path in (target, *(target.with_name(target.name + x) for x in ("-wal", "-shm"))):
                path.unlink(missing_ok=True)
        raise type(exc)(f"{exc}; nothing was merged into {target}") from None
    for src, report in zip(sources, reports, strict=True):
        out.print(f"{src}: {len(report.added)} run(s) added, {len(report.updated)} updated, "
                  f"{len(report.present)} already present")
        for change in report.updated:
            out.print(f"  run {change.run_id}: {change.describe()}")
        for run_id in report.running:
            err.print(f"warning: {src}: run {run_id} is still running: not merged "
                      "(merge again when it has ended)")
        for run_id in report.busy:
            err.print(f"warning: {src}: run {run_id} is running in {target}: not updated "
                      "(merge again when it has ended)")
    return 0
