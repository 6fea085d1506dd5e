"""`rigtool calibrate`, `export-cal` and `report`: fit a run, write its vehicle artefacts and
its HTML report from what the calibration stored."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from rigtool.cli.calibration_table import calibration_table
from rigtool.cli.console import err, out
from rigtool.cli.options import CALIBRATIONS_OUT, DB, RUN, namespace, positive_int
from rigtool.dbpath import resolve_db_path
from rigtool.store import Store

if TYPE_CHECKING:
    from rigtool.analysis.results import CalibrationResult
    from rigtool.artefacts.vehicle import ExportOptions

DYNAMICS_HELP = ("calibrated step-response run of the same thruster whose time constants the "
                 "vehicle artefacts carry (default: the run's own, when it is one)")


def add_parsers(sub: argparse._SubParsersAction) -> None:
    from rigtool.artefacts.formats import MODULES

    formats = tuple(MODULES)  # the format registry, read when the parser is built
    p = sub.add_parser("calibrate", help="fit a run; write calibrations/<run-id>/ artefacts",
                       parents=[RUN, CALIBRATIONS_OUT, DB])
    p.add_argument("--report", action="store_true", help="also write the HTML report")
    p.add_argument("--base", metavar="RUN_ID", help="deep run giving the BETM coefficients of a "
                   "shallow run with speed and current feedback (quasi-cavitation stage; "
                   "default: the latest such deep run of the same thruster)")
    p.add_argument("--causal", action="store_true", help="quasi-cavitation model on past "
                   "current only (for a controller; default: a centred 1 s window)")
    p.add_argument("--train-with", metavar="RUN", action="append", default=[],
                   help="also train the quasi-cavitation model on this shallow run of the same "
                   "thruster (repeatable; two runs or more are recommended)")
    p.add_argument("--export", metavar="FORMAT", action="append", default=[],
                   choices=formats, help="also write a vehicle artefact: "
                   f"{', '.join(formats)} (repeatable; docs/artefacts.md)")
    p.add_argument("--dynamics", metavar="RUN", help=DYNAMICS_HELP)
    _export_options(p)
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("export-cal", help="write vehicle and simulator artefacts of a "
                       "calibrated run (docs/artefacts.md)", parents=[RUN, CALIBRATIONS_OUT, DB])
    p.add_argument("--format", action="append", required=True, choices=formats,
                   help="artefact to write (repeatable)")
    p.add_argument("--dynamics", metavar="RUN", help=DYNAMICS_HELP)
    _export_options(p)
    p.set_defaults(func=cmd_export_cal)

    p = sub.add_parser("report", help="write calibrations/<run-id>/report.html from what "
                       "`calibrate` stored, and print its path",
                       parents=[RUN, CALIBRATIONS_OUT, DB])
    p.set_defaults(func=cmd_report)


def _export_options(p: argparse.ArgumentParser) -> None:
    """The options of the vehicle artefacts: names in the vehicle's model."""
    p.add_argument("--joint", help="propeller joint in the vehicle model (gazebo, uuv, "
                   "auv-controllers)")
    p.add_argument("--link", help="thruster or propeller link in the vehicle model (uuv, "
                   "stonefish)")
    p.add_argument("--namespace", type=namespace, help="robot or topic namespace (gazebo, uuv): "
                   "names of letters, digits and _ joined by /")
    p.add_argument("--mesh", help="the propeller's mesh file in the vehicle model (stonefish)")
    p.add_argument("--material", help="the propeller's material in the scenario (stonefish)")
    p.add_argument("--index", type=positive_int, help="the thruster's number on the vehicle, "
                   "from 1 (px4 CA_ROTOR{n}, uuv thruster id, auv-controllers names)")


def _options(args: argparse.Namespace) -> ExportOptions:
    from rigtool.artefacts.vehicle import ExportOptions

    return ExportOptions(joint=args.joint, link=args.link, namespace=args.namespace,
                         index=args.index, mesh=args.mesh, material=args.material)


def cmd_calibrate(args: argparse.Namespace) -> int:
    from rigtool import workflows

    with Store(resolve_db_path(args.db), create=False) as store:
        check = None
        if args.export:
            check = workflows.export_check(store, args.run, args.export,
                                           dynamics_run=args.dynamics, options=_options(args))
        res = workflows.calibrate(store, args.run, args.out, base=args.base, causal=args.causal,
                                  train_with=args.train_with, check=check)
        cal = res.calibration
        out.print(calibration_table(cal, res.run_id))
        out.print(f"artefacts: {', '.join(str(p) for p in res.paths)}")
        if res.cavitation is not None:
            out.print(f"quasi-cavitation model from BETM base run {res.cavitation.base_run_id}")
        _print_warnings(store, res.run_id, cal, res.notes)
        if args.export:
            paths = workflows.export_calibration(store, res.run_id, args.out, args.export,
                                                 results=res, dynamics_run=args.dynamics,
                                                 options=_options(args))
            out.print(f"vehicle artefacts: {', '.join(str(p) for p in paths)}")
        if args.report:
            out.print(f"report: {workflows.report(store, res.run_id, args.out, results=res)}")
    return 0


def cmd_export_cal(args: argparse.Namespace) -> int:
    from rigtool import workflows

    with Store(resolve_db_path(args.db), read_only=True) as store:
        for path in workflows.export_calibration(store, args.run, args.out, args.format,
                                                 dynamics_run=args.dynamics,
                                                 options=_options(args)):
            out.print(str(path))
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    from rigtool import workflows

    with Store(resolve_db_path(args.db), read_only=True) as store:
        run_id = store.resolve_run_id(args.run)
        res = workflows.stored_results(store, run_id)
        _print_warnings(store, run_id, res.calibration, res.notes)
        out.print(str(workflows.report(store, run_id, args.out, results=res)))
    return 0


def _print_warnings(store: Store, run_id: str, cal: CalibrationResult | None, notes: list[str]) -> None:
    """Print the run's warnings: the same list the report shows."""
    from rigtool.run_warnings import stored_run_warnings

    for warning in stored_run_warnings(store, run_id, cal, notes):
        err.print(f"warning: {warning}")
