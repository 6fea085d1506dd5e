"""`rigtool import`: store existing thrust-stand logs (CSV, .xlsx workbooks) as runs."""

from __future__ import annotations

import argparse
import os

from rigtool.cli.console import err, out
from rigtool.cli.options import DB
from rigtool.dbpath import resolve_db_path
from rigtool.errors import UsageError
from rigtool.ids import folder_problem, label_problem
from rigtool.progress import stage
from rigtool.store import Store

MAX_PRINTED_ERRORS = 200  # unreadable cells of one imported file listed on stderr


def add_parsers(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("import", help="store existing thrust-stand logs (Tyto/RCbenchmark, "
                       "manufacturer tables and .xlsx workbooks, any CSV) as runs", parents=[DB])
    p.add_argument("files", nargs="+", metavar="FILE",
                   help="CSV log(s) or .xlsx workbook(s) (one sheet per supply voltage, e.g. "
                        "'16 V'; needs pip install 'rigtool[xlsx]'); one run per file")
    p.add_argument("--mapping", help="YAML column mapping (docs/import.md)")
    p.add_argument("--col", action="append", metavar="FIELD=COLUMN",
                   help="map a column: time, command, thrust, speed, current, voltage (bus, "
                        "measured), supply (the supply voltage set: one calibration per "
                        "voltage; a `Supply Voltage (V)` column is recognised), depth, "
                        "thrust_std, n_samples, torque (about the thrust axis: C_q), "
                        "temperature (kept per point) (repeatable)")
    p.add_argument("--unit", action="append", metavar="FIELD=UNIT",
                   help="unit of a mapped column, e.g. thrust=kgf (overrides the header suffix)")
    p.add_argument("--command-unit", help="pulse_us | percent | pwm_counts | rpm | amps | volts "
                   "(default: from the command header's unit, e.g. `Throttle (V)`: volts)")
    p.add_argument("--neutral", type=float, help="stop command (default: 1500 us, else 0, "
                   "which must then lie within the logged commands)")
    p.add_argument("--decimal-comma", action="store_true", help="numbers use ',' as decimal sep. "
                   "(delimiter then defaults to ';')")
    p.add_argument("--delimiter", help="field delimiter (default: sniffed from the header)")
    p.add_argument("--format", choices=("auto", "timeseries", "points", "steps", "ramp"),
                   help="time series (rows grouped by command), one row per point, or `steps`: "
                        "a step log kept whole, imported as a step-response run")
    p.add_argument("--settle-s", type=float, help="time series: drop this many seconds at the "
                   "start of each command")
    p.add_argument("--pole-pairs", type=int, help="motor pole pairs, to convert electrical r/min")
    p.add_argument("--flip-thrust", action="store_true", help="negate the thrust column")
    p.add_argument("--sensor-accuracy", metavar="KEY=VALUE,...",
                   help="the force sensor's datasheet accuracy, %% of full scale: nonlinearity, "
                        "hysteresis, crosstalk (and full_scale in N), e.g. nonlinearity=0.25,"
                        "crosstalk=1.5,full_scale=100: added to the thrust coefficients' "
                        "intervals (docs/protocols.md)")
    p.add_argument("--depth", type=float, help="propeller depth (m) of every point")
    p.add_argument("--name", help="run name (default: the file name)")
    p.add_argument("--thruster-id", help="thruster id stored in the run metadata")
    p.add_argument("--strict", action="store_true", help="import nothing if any row is unreadable")
    p.set_defaults(func=cmd_import)


def cmd_import(args: argparse.Namespace) -> int:
    from rigtool.importers import Mapping, import_file, load_mapping, with_overrides
    from rigtool.importers.mapping import accuracy_option

    for option, text in (("--name", args.name), ("--thruster-id", args.thruster_id)):
        problem = label_problem(text) if text is not None else None
        if problem:
            raise UsageError(f"{option}: {problem}")
    problem = folder_problem("thruster_id", args.thruster_id) if args.thruster_id else None
    if problem:
        raise UsageError(f"--thruster-id: {problem}, so `rigtool export --all` could not file "
                         "the run")
    base = load_mapping(args.mapping) if args.mapping else Mapping()
    mapping = with_overrides(
        base, cols=args.col, units=args.unit, command_unit=args.command_unit,
        decimal="," if args.decimal_comma else None, delimiter=args.delimiter,
        format=args.format, settle_s=args.settle_s, pole_pairs=args.pole_pairs,
        neutral=args.neutral, thrust_sign=-1 if args.flip_thrust else None,
        sensor_accuracy=accuracy_option(args.sensor_accuracy))
    with Store(resolve_db_path(args.db)) as store:
        several = len(args.files) > 1
        for path in args.files:
            name = f"{args.name}-{os.path.splitext(os.path.basename(path))[0]}" if (
                args.name and several) else args.name
            with stage(f"importing {path}"):
                result = import_file(store, path, mapping, name=name,
                                     thruster_id=args.thruster_id, depth_m=args.depth,
                                     strict=args.strict)
            for line in result.errors[:MAX_PRINTED_ERRORS]:
                err.print(line)
            if len(result.errors) > MAX_PRINTED_ERRORS:
                err.print(f"... and {len(result.errors) - MAX_PRINTED_ERRORS} more unreadable "
                          "cell(s)")
            for warning in result.warnings:
                err.print(f"warning: {warning}")
            out.print(result.summary())
        return 0
