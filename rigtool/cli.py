"""Command line: parses arguments, calls one layer, prints. Exit 2 on usage/config errors."""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from rich.console import Console
from rich.table import Column, Table
from rich.text import Text

from rigtool import __version__
from rigtool.errors import DataError, RigtoolError, UsageError
from rigtool.progress import default_reporter, stage
from rigtool.store import DB_ENV, Store, resolve_db_path
from rigtool.units import unit_label

if TYPE_CHECKING:
    from rigtool.analysis.results import CalibrationResult
    from rigtool.artefacts.vehicle import ExportOptions
    from rigtool.engine import Outcome

# Pipes and logs get wide tables instead of rich's 80-column default.
# markup off: run names, reasons and file contents are printed literally, never as Rich markup
out = Console(highlight=False, markup=False, soft_wrap=True,
              width=None if sys.stdout.isatty() else 160)
err = Console(stderr=True, highlight=False, markup=False, soft_wrap=True,
              width=None if sys.stderr.isatty() else 160)


VEHICLE_FORMATS = ("c-header", "ros2", "gazebo", "csv-lut", "ardupilot", "px4", "uuv",
                   "stonefish", "thruster-manager", "auv-controllers")  # artefacts.formats
MAX_PRINTED_ERRORS = 200  # unreadable cells of one imported file listed on stderr
EXIT_INTERRUPTED = 130  # 128 + SIGINT: the operator's Ctrl-C stopped the command


def _fmt_duration(seconds: float) -> str:
    h, rem = divmod(int(round(seconds)), 3600)
    m, s = divmod(rem, 60)
    return f"{h} h {m:02d} min" if h else f"{m} min {s:02d} s"


def cmd_sweep(args: argparse.Namespace) -> int:
    from rigtool.sweep import (
        check_dry_run,
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
                run_id = store.resolve_run_id(args.resume)
                if store.run(run_id)["status"] == "running":
                    store.finish_run(run_id, "interrupted", "marked interrupted by --force")
            reporter = default_reporter()
            with _closing_signals(reporter), _watching(args.watch, store.path, args.bind):
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
        with _closing_signals(reporter), _watching(args.watch, store.path, args.bind):
            outcome = run_sweep(setup, store, reporter, terminal_confirm())
            return _report_outcome(outcome, setup.protocol.n_points(), store)
    finally:
        store.close()


@contextlib.contextmanager
def _watching(port: int | None, db: Path, bind: str):
    """With `--watch`: the watch server in a daemon thread beside the sweep, reading the
    latest run through its own read-only connection; a server that cannot start is a
    warning, never a reason to stop the sweep."""
    if port is None:
        yield
        return
    server = None
    try:
        from rigtool.watch import Watcher, WatchServer

        server = WatchServer(Watcher(db, follow=True), port, bind)
        server.serve_in_thread()
        _announce_watch(server.url, bind)
    except (OSError, RigtoolError) as exc:
        err.print(f"warning: rigtool watch could not start ({exc}); the sweep goes on without it")
    try:
        yield
    finally:
        if server is not None:
            with contextlib.suppress(BaseException):  # the run is closed: nothing to mask
                server.stop()


def _announce_watch(url: str, bind: str) -> None:
    """Where the watch page is, and a warning when it is reachable from the network."""
    from rigtool.watch.server import is_loopback

    err.print(f"watch the run at {url} (read-only; Ctrl-C stops it)")
    if not is_loopback(bind):
        err.print(f"warning: the watch page is served on {bind}: anyone who can reach this "
                  "host can read the run (names, events, data); it commands nothing")


def cmd_watch(args: argparse.Namespace) -> int:
    from rigtool.watch import Watcher, WatchServer

    watcher = Watcher(resolve_db_path(args.db), args.run)
    try:
        run_id = watcher.start()
        server = WatchServer(watcher, args.port, args.bind)
    except BaseException:
        watcher.close()
        raise
    out.print(f"run {run_id}")
    _announce_watch(server.url, args.bind)
    try:
        with stop_on_signals():
            server.serve_forever(poll_interval=0.5)
    except KeyboardInterrupt:
        err.print("rigtool watch: stopped")
    finally:
        server.server_close()
        watcher.close()
    return 0


def _port(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r} is not a port (0 .. 65535; 0: any free port)")
    return value


def _report_outcome(outcome: Outcome, n_plan: int, store: Store) -> int:
    """Print how the run ended; return its exit status (`_exit_status`)."""
    steps = f"{len(store.steps(outcome.run_id))}/{n_plan} points"
    if outcome.status == "completed" and outcome.neutral_ok:
        out.print(f"run {outcome.run_id} completed: {steps} stored in {store.path}")
    elif not outcome.neutral_ok:
        err.print(f"run {outcome.run_id} {outcome.status}: {outcome.reason}; {steps} kept in {store.path}. "
                  "ERROR: THE NEUTRAL COMMAND FAILED: check the thruster and cut its power.")
    else:
        err.print(f"run {outcome.run_id} {outcome.status}: {outcome.reason}; {steps} kept in "
                  f"{store.path}; actuator at neutral. Continue with: "
                  f"rigtool sweep --resume {outcome.run_id} --db {store.path}")
    return _exit_status(outcome)


def _exit_status(outcome: Outcome) -> int:
    """0 completed, 3 the actuator may not be at neutral, 130 stopped by Ctrl-C, 1 otherwise."""
    from rigtool.engine import NeutralNotConfirmed

    if not outcome.neutral_ok:
        return NeutralNotConfirmed.exit_status
    if outcome.status == "completed":
        return 0
    return EXIT_INTERRUPTED if outcome.interrupted else 1


def _print_plan(setup, neutral: float) -> None:
    """The plan's size, timing and first and last steps, all counted without expanding it."""
    from rigtool.plan import estimate_duration_s, step_at

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
    out.print(f"  per point: settle {timing.settle.max_seconds():g} s max, acquire "
              f"{timing.acquire.n_samples} samples at {timing.acquire.rate_hz:g} Hz, rest {timing.rest_s:g} s; "
              f"tare {timing.tare}")
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


def cmd_runs(args: argparse.Namespace) -> int:
    with Store(resolve_db_path(args.db), read_only=True) as store:
        rows = store.runs(limit=args.limit)
        if not rows:
            out.print(f"no runs in {store.path}")
            return 0
        table = Table("name", "status", "created (UTC)", "points", "unit")
        table.columns.insert(0, Column("run id", no_wrap=True))
        for r in rows:
            table.add_row(r["id"], r["name"], r["status"], r["created_utc"][:16].replace("T", " "),
                          f"{r['n_steps']}/{r['n_planned']}", r["command_unit"])
        out.print(table)
        return 0


def cmd_show(args: argparse.Namespace) -> int:
    with Store(resolve_db_path(args.db), read_only=True) as store:
        run_id = store.resolve_run_id(args.run)
        run = store.run(run_id)
        steps = store.steps(run_id)
        out.print(Text.assemble((f"run {run_id}", "bold"), f"  {run['name']}  status ",
                                (run["status"], "bold"),
                                f" ({run['stop_reason']})" if run["stop_reason"] else ""))
        out.print(f"  created {run['created_utc']}, finished {run['finished_utc'] or '-'}, "
                  f"host {run['host']}, rigtool {run['tool_version']}"
                  + ("" if run["seed"] is None else f", simulator seed {run['seed']}"))
        out.print(f"  rig: {run['rig'].get('name')}  protocol: {run['protocol_path']}")
        if run["actuator"]:
            out.print("  actuator: " + _actuator_text(run["actuator"]))
        meta = {k: v for k, v in run["metadata"].items() if v not in (None, {}, "")}
        if meta:
            out.print("  metadata: " + ", ".join(f"{k}={v}" for k, v in meta.items()))
        out.print(f"  points: {len(steps)}/{run['n_planned']}, samples: {sum(s['n'] for s in steps):,}")
        unit = unit_label(run["command_unit"])
        table = Table("depth (m)", "points", f"command ({unit})", "thrust mean (N)", "speed (r/min)",
                      "current (A)", title="per-depth summary")
        depths = {s["depth_m"] for s in steps}  # None: an import that recorded no depth
        for depth in sorted(depths, key=lambda d: (d is None, d or 0.0)):
            ds = [s for s in steps if s["depth_m"] == depth]
            table.add_row("not recorded" if depth is None else f"{depth:g}", str(len(ds)), _span(ds, "command"), _span(ds, "thrust_n_mean"),
                          _span(ds, "speed_rpm_mean"), _span(ds, "current_a_mean"))
        out.print(table)
        counts: dict[str, int] = {}
        for ev in store.events(run_id):
            counts[ev["kind"]] = counts.get(ev["kind"], 0) + 1
        if counts:
            out.print("  events: " + ", ".join(f"{k} x{v}" for k, v in sorted(counts.items())))
        for line in _counters_lines(store.transport_counters(run_id), len(steps)):
            out.print(line)
        return 0


def _counters_lines(summary: dict, n_points: int) -> list[str]:
    """Transport counters over the stored points, and which points had problems, for `show`."""
    if not summary["totals"]:
        return ["  transport counters: none stored (simulated devices, or an older run)"]
    lines = ["  transport counters over the stored points:"]
    for role, counters in summary["totals"].items():
        lines.append(f"    {role}: " + ", ".join(f"{k}={v}" for k, v in counters.items()))
    bad = summary["problem_points"]
    shown = ", ".join(str(i) for i in bad[:10]) + (", ..." if len(bad) > 10 else "")
    lines.append(f"  points with lost, garbage or failed frames: {len(bad)} of {n_points}"
                 + (f" (points {shown})" if bad else ""))
    return lines


def _actuator_text(actuator: dict) -> str:
    """Neutral, range and feedback of a stored actuator record, for `show`."""
    unit = unit_label(actuator["command_unit"])
    feedback = ", ".join(actuator.get("feedback") or ()) or "none"
    return (f"neutral {actuator['neutral']:g} {unit}, range {actuator['command_min']:g} .. "
            f"{actuator['command_max']:g} {unit}, feedback {feedback}")


def _span(rows: list[dict], key: str) -> str:
    vals = [r[key] for r in rows if r[key] is not None]
    return f"{min(vals):.4g} .. {max(vals):.4g}" if vals else "-"


def cmd_export(args: argparse.Namespace) -> int:
    from rigtool.export import export_all, export_run

    if (args.run is None) == (args.all is None):
        raise UsageError("give a run to export, or --all DIR for every run")
    with Store(resolve_db_path(args.db), read_only=True) as store:
        if args.all is not None:
            if args.format == "csv":
                raise UsageError("--all writes a Parquet dataset: drop --format csv")
            with stage(f"exporting every run of {store.path} to {args.all}"):
                paths = export_all(store, Path(args.all))
            out.print(f"{len(paths)} files in {args.all} (docs/sql.md shows how to query them)")
            return 0
        run_id = store.resolve_run_id(args.run)
        with stage(f"exporting run {run_id}"):
            paths = export_run(store, run_id, Path(args.out), args.format or "csv")
        for path in paths:
            out.print(str(path))
    return 0


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
        with Store(target) as store, stage(f"merging {len(sources)} database(s) into {target}"):
            reports = store.merge_from(sources)
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


class Stopped(KeyboardInterrupt):
    """A signal stopped the command outside a run (opening devices): SIGINT exits 130, others
    1, as a run stopped by them does."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


@contextlib.contextmanager
def _closing_signals(reporter: object):
    """Around a sweep: a signal before the run starts stops the command (devices closed); once
    the run has ended (the actuator sent to neutral), a further signal while the rig closes and
    the outcome prints is only noted, so the exit status stays the run's."""
    def _on_signal(signum: int, frame: object) -> None:
        if getattr(reporter, "finished", False):
            err.print(f"rigtool: {signal.Signals(signum).name} while closing: the run has "
                      "ended; finishing")
            return
        raise Stopped(signum)

    sigs = [s for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
            if signal.getsignal(s) is not signal.SIG_IGN]
    old = {sig: signal.signal(sig, _on_signal) for sig in sigs}
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


@contextlib.contextmanager
def stop_on_signals():
    """Turn SIGTERM/SIGHUP into KeyboardInterrupt so `finally` blocks (neutral) still run."""
    def _raise(signum, frame):
        raise KeyboardInterrupt(signal.Signals(signum).name)

    old = {sig: signal.signal(sig, _raise) for sig in (signal.SIGTERM, signal.SIGHUP)}
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


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


def cmd_sim(args: argparse.Namespace) -> int:
    import signal
    import threading

    from rigtool.sim.server import start_sim

    server = start_sim(args.profile, seed=args.seed, sensor=args.sensor, netft=args.netft,
                       can_channel=args.can_channel, depth_m=args.depth, bind=args.bind,
                       rate_hz=args.rate)
    try:
        for spec in args.fault or ():
            server.set_fault(spec)
    except BaseException:
        server.stop()
        raise
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, lambda *_: stop.set())
    try:
        text = server.rig_yaml()
        if args.rig_out:
            tmp = f"{args.rig_out}.tmp"
            with open(tmp, "w", encoding="utf-8") as fh:
                fh.write(text)
            os.replace(tmp, args.rig_out)
            err.print(f"rig file written to {args.rig_out}")
        for warning in server.exposure():
            err.print(f"warning: {warning}")
        out.print(f"# rigtool sim --profile {args.profile}: use this rig file "
                  "(rigtool sweep PROTOCOL --rig FILE); Ctrl-C stops the simulator")
        out.print(text)
        sys.stdout.flush()
        stop.wait()
    finally:
        server.stop()
    return 0


def _num(v: float) -> str:
    return "" if v != v else f"{v:.5g}"  # NaN -> blank


def cmd_calibrate(args: argparse.Namespace) -> int:
    from rigtool import workflows
    from rigtool.analysis.calibrate import summary_rows

    with Store(resolve_db_path(args.db), create=False) as store:
        check = None
        if args.export:
            check = workflows.export_check(store, args.run, args.export,
                                           dynamics_run=args.dynamics, options=_options(args))
        res = workflows.calibrate(store, args.run, args.out, base=args.base, causal=args.causal,
                                  train_with=args.train_with, check=check)
        cal = res.calibration
        table = Table("quantity", "value", "95 % interval", "unit", "note",
                      title=f"calibration of run {res.run_id} ({cal.run_name})")
        for name, value, lo, hi, unit, note in summary_rows(cal):
            interval = f"{_num(lo)} .. {_num(hi)}" if lo == lo or hi == hi else ""
            table.add_row(name, _num(value), interval, unit, note)
        out.print(table)
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


def _print_warnings(store: Store, run_id: str, cal: CalibrationResult | None, notes: list[str]) -> None:
    """Print the run's warnings: the same list the report shows."""
    from rigtool.run_warnings import stored_run_warnings

    for warning in stored_run_warnings(store, run_id, cal, notes):
        err.print(f"warning: {warning}")


def cmd_report(args: argparse.Namespace) -> int:
    from rigtool import workflows

    with Store(resolve_db_path(args.db), read_only=True) as store:
        run_id = store.resolve_run_id(args.run)
        res = workflows.stored_results(store, run_id)
        _print_warnings(store, run_id, res.calibration, res.notes)
        out.print(str(workflows.report(store, run_id, args.out, results=res)))
    return 0


def cmd_import(args: argparse.Namespace) -> int:
    from rigtool.importers import Mapping, import_file, load_mapping, with_overrides

    base = load_mapping(args.mapping) if args.mapping else Mapping()
    mapping = with_overrides(
        base, cols=args.col, units=args.unit, command_unit=args.command_unit,
        decimal="," if args.decimal_comma else None, delimiter=args.delimiter,
        format=args.format, settle_s=args.settle_s, pole_pairs=args.pole_pairs,
        neutral=args.neutral, thrust_sign=-1 if args.flip_thrust else None)
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


def cmd_export_cal(args: argparse.Namespace) -> int:
    from rigtool import workflows

    with Store(resolve_db_path(args.db), read_only=True) as store:
        for path in workflows.export_calibration(store, args.run, args.out, args.format,
                                                 dynamics_run=args.dynamics,
                                                 options=_options(args)):
            out.print(str(path))
    return 0


def _options(args: argparse.Namespace) -> ExportOptions:
    from rigtool.artefacts.vehicle import ExportOptions

    return ExportOptions(joint=args.joint, link=args.link, namespace=args.namespace,
                         index=args.index, mesh=args.mesh, material=args.material)


def _export_options(p: argparse.ArgumentParser) -> None:
    """The options of the vehicle artefacts: names in the vehicle's model."""
    p.add_argument("--joint", help="propeller joint in the vehicle model (gazebo, uuv, "
                   "auv-controllers)")
    p.add_argument("--link", help="thruster or propeller link in the vehicle model (uuv, "
                   "stonefish)")
    p.add_argument("--namespace", help="robot or topic namespace (gazebo)")
    p.add_argument("--mesh", help="the propeller's mesh file in the vehicle model (stonefish)")
    p.add_argument("--material", help="the propeller's material in the scenario (stonefish)")
    p.add_argument("--index", type=_positive_int, help="the thruster's number on the vehicle, "
                   "from 1 (px4 CA_ROTOR{n}, uuv thruster id, auv-controllers names)")


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number from 1")
    return value


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


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="rigtool", description="Sweep, calibrate and report on underwater thrusters.")
    parser.add_argument("--version", action="version", version=f"rigtool {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    db_help = f"run database (default: ${DB_ENV}, the rig file's db, or ./rigtool.sqlite)"

    p = sub.add_parser("sweep", help="run a protocol on a rig and store the run")
    p.add_argument("protocol", nargs="?", help="protocol YAML file")
    p.add_argument("--resume", metavar="RUN_ID", help="continue a stopped run from its first unfinished point")
    p.add_argument("--force", action="store_true",
                   help="with --resume: take over a run still marked running (its process is gone "
                        "but was on another host, or its pid was reused)")
    p.add_argument("--rig", help="rig YAML file (overrides the protocol's `rig:`)")
    p.add_argument("--sim", action="store_true", help="run on the built-in simulator twin")
    p.add_argument("--seed", type=int, help="simulator seed (overrides the protocol's)")
    p.add_argument("--dry-run", action="store_true", help="print the plan and estimated duration only")
    p.add_argument("--db", help=db_help)
    p.add_argument("--watch", nargs="?", type=_port, const=8765, metavar="PORT",
                   help="also serve the read-only watch page of the run (default port 8765; "
                        "docs/watch.md)")
    p.add_argument("--bind", default="127.0.0.1", metavar="ADDRESS",
                   help="with --watch: address to serve on (default 127.0.0.1: this host only)")
    p.set_defaults(func=cmd_sweep)

    p = sub.add_parser("watch", help="serve a local, read-only web page following a run "
                       "(docs/watch.md)")
    p.add_argument("run", nargs="?", default="last",
                   help="run id, unique prefix, or `last` (default: the run most recently started)")
    p.add_argument("--port", type=_port, default=8765, help="port (default 8765; 0: any free port)")
    p.add_argument("--bind", default="127.0.0.1", metavar="ADDRESS",
                   help="address to serve on (default 127.0.0.1: this host only; another "
                        "address opens the page to the network)")
    p.add_argument("--db", help=db_help)
    p.set_defaults(func=cmd_watch)

    p = sub.add_parser("runs", help="list runs in the database")
    p.add_argument("--limit", type=int, default=50)
    p.add_argument("--db", help=db_help)
    p.set_defaults(func=cmd_runs)

    p = sub.add_parser("show", help="metadata and per-depth summary of one run")
    p.add_argument("run", help="run id, unique prefix, or `last`")
    p.add_argument("--db", help=db_help)
    p.set_defaults(func=cmd_show)

    p = sub.add_parser("calibrate", help="fit a run; write calibrations/<run-id>/ artefacts")
    p.add_argument("run", help="run id, unique prefix, or `last`")
    p.add_argument("--out", default="calibrations", help="output folder (default: ./calibrations)")
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
                   choices=VEHICLE_FORMATS, help="also write a vehicle artefact: "
                   f"{', '.join(VEHICLE_FORMATS)} (repeatable; docs/artefacts.md)")
    p.add_argument("--dynamics", metavar="RUN", help="calibrated step-response run of the same "
                   "thruster whose time constants the vehicle artefacts carry (default: the "
                   "run's own, when it is one)")
    _export_options(p)
    p.add_argument("--db", help=db_help)
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("export-cal", help="write vehicle and simulator artefacts of a "
                       "calibrated run (docs/artefacts.md)")
    p.add_argument("run", help="run id, unique prefix, or `last`")
    p.add_argument("--format", action="append", required=True, choices=VEHICLE_FORMATS,
                   help="artefact to write (repeatable)")
    p.add_argument("--out", default="calibrations", help="output folder (default: ./calibrations)")
    p.add_argument("--dynamics", metavar="RUN", help="calibrated step-response run of the same "
                   "thruster whose time constants the vehicle artefacts carry (default: the "
                   "run's own, when it is one)")
    _export_options(p)
    p.add_argument("--db", help=db_help)
    p.set_defaults(func=cmd_export_cal)

    p = sub.add_parser("report", help="write calibrations/<run-id>/report.html from what "
                       "`calibrate` stored, and print its path")
    p.add_argument("run", help="run id, unique prefix, or `last`")
    p.add_argument("--out", default="calibrations", help="output folder (default: ./calibrations)")
    p.add_argument("--db", help=db_help)
    p.set_defaults(func=cmd_report)

    p = sub.add_parser("check", help="open a rig's devices, read for a few seconds, print rates and noise")
    p.add_argument("rig", help="rig YAML file")
    p.add_argument("--seconds", type=float, default=3.0)
    p.add_argument("--rate", type=float, default=1000.0, help="requested sample rate (Hz)")
    p.add_argument("--command", type=float, help="test command to hold while reading (default: neutral only)")
    p.set_defaults(func=cmd_check)

    p = sub.add_parser("sim", help="run the simulator twin on real transports and print its rig file")
    p.add_argument("--profile", default="stm32-pwm", help="can-bldc | stm32-pwm | esc-1100-1900")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--sensor", default="netft", help="netft | mark10 | hx711")
    p.add_argument("--bind", default="127.0.0.1", metavar="ADDRESS",
                   help="address the network personalities serve on (default 127.0.0.1: this "
                        "host only; e.g. 0.0.0.0 makes the simulator reachable from the LAN)")
    p.add_argument("--netft", metavar="[HOST:]PORT",
                   help="where the Net F/T answers (default: the --bind address, port 49152; "
                        "port 0: any free port)")
    p.add_argument("--can-channel", metavar="GROUP[:PORT]",
                   help="multicast group (239.x.y.z) of the CAN personalities' bus (default: a "
                        "random group and a free port, so every simulator has its own bus)")
    p.add_argument("--depth", type=float, default=1.0, help="initial propeller depth (m)")
    p.add_argument("--rate", type=float, default=1000.0, metavar="HZ",
                   help="samples per second of the twin, and the Net F/T's RDT rate (default "
                        "1000; the real box goes up to 7000)")
    p.add_argument("--fault", action="append", metavar="PART.SWITCH=VALUE",
                   help="inject a fault, e.g. netft.drop=0.01, netft.silent=true, bridge.garbage=true, "
                        "bridge.no_replies=true, vesc.fault_code=4, vesc.deaf=true, stage.stalled=true "
                        "(repeatable)")
    p.add_argument("--rig-out", help="also write the rig file here")
    p.set_defaults(func=cmd_sim)

    p = sub.add_parser("export", help="write a run's points, samples and events as CSV or "
                       "Parquet, or every run as a Parquet dataset (--all)")
    p.add_argument("run", nargs="?", help="run id, unique prefix, or `last`")
    p.add_argument("--format", choices=("csv", "parquet"),
                   help="file format (default: csv; parquet with --all)")
    p.add_argument("--out", default="exports", help="output folder (default: ./exports)")
    p.add_argument("--all", metavar="DIR", help="write every run as a Parquet dataset in DIR: "
                   "runs, calibrations, and points/samples/events per run (docs/sql.md)")
    p.add_argument("--db", help=db_help)
    p.set_defaults(func=cmd_export)

    p = sub.add_parser("merge", help="merge the run databases of several rigs into one")
    p.add_argument("stores", nargs="+", metavar="DB", help="run databases to merge")
    p.add_argument("-o", "--output", required=True, metavar="DB",
                   help="merged database (created, or added to; runs already there are skipped)")
    p.set_defaults(func=cmd_merge)

    p = sub.add_parser("import", help="store existing thrust-stand logs (Tyto/RCbenchmark, "
                       "manufacturer tables and .xlsx workbooks, any CSV) as runs")
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
    p.add_argument("--command-unit", help="pulse_us | percent | pwm_counts | rpm | amps")
    p.add_argument("--neutral", type=float, help="stop command (default: 1500 us, else 0)")
    p.add_argument("--decimal-comma", action="store_true", help="numbers use ',' as decimal sep. "
                   "(delimiter then defaults to ';')")
    p.add_argument("--delimiter", help="field delimiter (default: sniffed from the header)")
    p.add_argument("--format", choices=("auto", "timeseries", "points", "steps"),
                   help="time series (rows grouped by command), one row per point, or `steps`: "
                        "a step log kept whole, imported as a step-response run")
    p.add_argument("--settle-s", type=float, help="time series: drop this many seconds at the "
                   "start of each command")
    p.add_argument("--pole-pairs", type=int, help="motor pole pairs, to convert electrical r/min")
    p.add_argument("--flip-thrust", action="store_true", help="negate the thrust column")
    p.add_argument("--depth", type=float, help="propeller depth (m) of every point")
    p.add_argument("--name", help="run name (default: the file name)")
    p.add_argument("--thruster-id", help="thruster id stored in the run metadata")
    p.add_argument("--strict", action="store_true", help="import nothing if any row is unreadable")
    p.add_argument("--db", help=db_help)
    p.set_defaults(func=cmd_import)

    p = sub.add_parser("compare", help="compare thrusters (runs); write corrections and a report")
    p.add_argument("runs", nargs="+", metavar="RUN", help="run ids, unique prefixes, or `last`")
    p.add_argument("--reference", metavar="RUN", help="match this run (default: the mean of the runs)")
    p.add_argument("--floor-frac", type=float, default=0.1,
                   help="ignore thrust below this fraction of the shared maximum (default 0.1)")
    p.add_argument("--out", default="calibrations/compare", help="output folder")
    p.add_argument("--db", help=db_help)
    p.set_defaults(func=cmd_compare)
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
        return 1
    except KeyboardInterrupt as exc:
        stopped_by = getattr(exc, "signum", signal.SIGINT)
        err.print("rigtool: interrupted" if stopped_by == signal.SIGINT
                  else f"rigtool: stopped by {signal.Signals(stopped_by).name}")
        return EXIT_INTERRUPTED if stopped_by == signal.SIGINT else 1


if __name__ == "__main__":
    sys.exit(main())
