"""`rigtool runs` and `rigtool show`: the runs of a database, and one run in detail."""

from __future__ import annotations

import argparse

from rich.table import Column, Table
from rich.text import Text

from rigtool.cli.console import out
from rigtool.cli.options import DB, RUN
from rigtool.dbpath import resolve_db_path
from rigtool.store import Store
from rigtool.units import unit_label


def add_parsers(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("runs", help="list runs in the database", parents=[DB])
    p.add_argument("--limit", type=int, default=50)
    p.set_defaults(func=cmd_runs)

    p = sub.add_parser("show", help="metadata and per-depth summary of one run",
                       parents=[RUN, DB])
    p.set_defaults(func=cmd_show)


def cmd_runs(args: argparse.Namespace) -> int:
    with Store(resolve_db_path(args.db), read_only=True) as store:
        rows = store.runs(limit=args.limit)
        if not rows:
            out.print(f"no runs in {store.path}")
            return 0
        table = Table("name", "status", "created (UTC)", "points", "unit", "calibrated (UTC)")
        table.columns.insert(0, Column("run id", no_wrap=True))
        for r in rows:
            table.add_row(r["id"], r["name"], r["status"], _minute(r["created_utc"]),
                          f"{r['n_steps']}/{r['n_planned']}", r["command_unit"],
                          _minute(r["calibrated_utc"]) if r["calibrated_utc"] else "no")
        out.print(table)
        return 0


def _minute(utc: str) -> str:
    """An ISO time to the minute, as the listing shows it."""
    return utc[:16].replace("T", " ")


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
            table.add_row("not recorded" if depth is None else f"{depth:g}", str(len(ds)), _span(ds, "command"), _span(ds, "thrust_all_mean_n"),
                          _span(ds, "speed_all_mean_rpm"), _span(ds, "current_all_mean_a"))
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
