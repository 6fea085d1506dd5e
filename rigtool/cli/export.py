"""`rigtool export`: a run's points, samples and events as CSV or Parquet, or every run as a
Parquet dataset."""

from __future__ import annotations

import argparse
from pathlib import Path

from rigtool.cli.console import err, out
from rigtool.cli.options import DB, RUN_HELP, out_folder
from rigtool.dbpath import resolve_db_path
from rigtool.errors import UsageError
from rigtool.progress import stage
from rigtool.store import Store

OUT = "exports"  # the default folder of a run's export and of the dataset


def add_parsers(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("export", help="write a run's points, samples and events as CSV or "
                       "Parquet, or every run as a Parquet dataset (--all --out DIR)",
                       parents=[out_folder(OUT, f"output folder, also the dataset's with --all "
                                                f"(default: ./{OUT})"), DB])
    p.add_argument("run", nargs="?", help=RUN_HELP)
    p.add_argument("--format", choices=("csv", "parquet"),
                   help="file format (default: csv; parquet with --all)")
    p.add_argument("--all", nargs="?", const=True, default=None, metavar="DIR",
                   help="bring the Hive-partitioned Parquet dataset in the --out folder up to "
                   "date: a partition per run (thruster_id=/run_id=), only changed runs "
                   "rewritten, a manifest (docs/sql.md); `--all DIR` is the older spelling")
    p.set_defaults(func=cmd_export)


def cmd_export(args: argparse.Namespace) -> int:
    from rigtool.export import export_run

    if (args.run is None) == (args.all is None):
        raise UsageError("give a run to export, or --all --out DIR for every run")
    folder = _dataset_folder(args) if args.all is not None else None
    with Store(resolve_db_path(args.db), read_only=True) as store:
        if folder is not None:
            if args.format == "csv":
                raise UsageError("--all writes a Parquet dataset: drop --format csv")
            from rigtool.dataset.update import export_dataset

            with stage(f"exporting every run of {store.path} to {folder}") as progress:
                done = export_dataset(store, Path(folder), progress)
            for why in done.skipped:
                err.print(f"warning: {why}: left out of the dataset")
            kept = f", {len(done.kept)} kept (not in this database)" if done.kept else ""
            kept += f", {len(done.skipped)} left out" if done.skipped else ""
            out.print(f"{folder}: {len(done.written)} run(s) written, {done.unchanged} "
                      f"unchanged{kept}; {done.runs} run(s), {done.rows:,} sample rows "
                      "(docs/sql.md shows how to query them)")
            return 0
        run_id = store.resolve_run_id(args.run)
        with stage(f"exporting run {run_id}"):
            paths = export_run(store, run_id, Path(args.out), args.format or "csv")
        for path in paths:
            out.print(str(path))
    return 0


def _dataset_folder(args: argparse.Namespace) -> str:
    """The dataset folder of `--all --out DIR`, or of the older `--all DIR` (with a note)."""
    if args.all is True:
        return args.out
    if args.out != OUT:
        raise UsageError(f"give the dataset's folder once: --all --out {args.all}")
    err.print(f"note: `--all DIR` is deprecated; write `--all --out {args.all}` (the same "
              "--out as a run's export)")
    return args.all
