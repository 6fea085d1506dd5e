"""`rigtool merge`: merge the run databases of several rigs into one.

Into an existing database the merge is one transaction: a reader, or a kill -9, sees it
before or after, never half done. A new output is built under a hidden name beside it
(`.NAME.merging`) and renamed into place once whole, so until then no file of that name
exists: never an empty or partly merged database."""

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
    building = target.with_name(f".{target.name}.merging") if created else target
    if created:  # left by a merge that was killed: never renamed into place, so never seen
        _remove_database(building)
    try:
        with (Store(building) as store,
              stage(f"merging {len(sources)} database(s) into {target}") as progress):
            reports = store.merge_from(sources, progress)
    except BaseException as exc:
        if created:  # a refused or interrupted merge leaves no database where there was none
            _remove_database(building)
        if isinstance(exc, (DataError, UsageError)):
            raise type(exc)(f"{exc}; nothing was merged into {target}") from None
        raise
    if created:
        if building.with_name(building.name + "-wal").exists():  # closing folds the log in
            raise DataError(f"{building}: the merged database's write-ahead log was not "
                            f"folded in when it closed; it is left there, not at {target}")
        building.replace(target)
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


def _remove_database(path: Path) -> None:
    """Delete a database file and its -wal and -shm files, where they are."""
    for part in (path, *(path.with_name(path.name + x) for x in ("-wal", "-shm"))):
        part.unlink(missing_ok=True)

