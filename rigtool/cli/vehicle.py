"""`rigtool identify` (the vehicle's hydrodynamic model from free-running logs) and
`rigtool sim-vehicle` (a free-running log of the vehicle twin, from known truth)."""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
from pathlib import Path

import numpy as np

from rigtool import api
from rigtool.analysis.vehicle.identify import METHODS
from rigtool.cli.console import out
from rigtool.errors import UsageError
from rigtool.progress import stage
from rigtool.sim.vehicle_params import BLUEROV2, BLUEROV2_HEAVY
from rigtool.sim.vehicle_twin import VehicleTwin, excitation, free_run
from rigtool.thruster_profiles import PROFILES

TRUTHS = {"bluerov2": BLUEROV2, "bluerov2-heavy": BLUEROV2_HEAVY}


def add_parsers(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("identify", help="identify the vehicle's added mass and damping from "
                                        "free-running logs (docs/vehicle.md)")
    p.add_argument("vehicle", help="the vehicle file (YAML): rigid body and thrusters")
    p.add_argument("logs", nargs="+", help="free-running logs (CSV)")
    p.add_argument("--out", default="vehicle-model", help="folder for vehicle_model.json, "
                   "identification.json and identification.html (default vehicle-model)")
    p.add_argument("--method", default="nls", choices=METHODS,
                   help="ls: equation-error least squares; nls: output error of the coupled "
                        "model (default); global: differential evolution first; all: every one")
    p.add_argument("--dofs", help="comma-separated DOFs to identify (default all six): "
                                  "surge,sway,heave,roll,pitch,yaw")
    p.add_argument("--seed", type=int, default=1, help="seed of the bootstrap and the global search")
    p.add_argument("--link", default="base_link",
                   help="the vehicle's link in the gz-sim and uuv_simulator blocks (default base_link)")
    p.add_argument("--namespace", help="gz-sim: the namespace of the ocean-current topic")
    p.set_defaults(func=cmd_identify)
    s = sub.add_parser("sim-vehicle", help="write a free-running log of the vehicle twin and its "
                                           "vehicle file, from known truth")
    s.add_argument("--calibration", required=True,
                   help="the calibration folder of the twin thruster (rigtool calibrate of a run "
                        "of --profile) that every thruster of the vehicle file points to")
    s.add_argument("--out", default="vehicle-flight", help="folder for vehicle.yaml and log.csv")
    s.add_argument("--truth", default="bluerov2", choices=sorted(TRUTHS))
    s.add_argument("--profile", default="esc-1100-1900", help="the thrusters' twin profile")
    s.add_argument("--seed", type=int, default=1)
    s.add_argument("--duration", type=float, default=600.0, help="log length (s)")
    s.add_argument("--rate", type=float, default=20.0, help="log rate (Hz)")
    s.add_argument("--noise", type=float, default=0.03,
                   help="noise as a fraction of each channel's spread (default 0.03)")
    s.set_defaults(func=cmd_sim_vehicle)


def cmd_identify(args: argparse.Namespace) -> int:
    with stage(f"identifying {args.vehicle}") as progress:
        ident = api.identify_vehicle(args.vehicle, args.logs, args.out, method=args.method,
                                     dofs=args.dofs, seed=args.seed, link=args.link,
                                     namespace=args.namespace, progress=progress)
    out.print(f"identified {', '.join(ident.dofs)} ({ident.method}); wrote {args.out}/")
    for p in ident.parameters:
        if p.value is None:
            out.print(f"  {p.name:7s}  -  {p.reason}")
        elif p.low is None:
            out.print(f"  {p.name:7s} {p.value:11.4g}   ({p.reason})")
        else:
            out.print(f"  {p.name:7s} {p.value:11.4g}   95 % {p.low:.4g} .. {p.high:.4g}")
    worst = max(ident.held_out, key=lambda h: h.percent)
    out.print(f"held-out prediction: worst {worst.dof} {worst.percent:.2f} % of its range")
    for note in ident.notes:
        out.print(f"note: {note}")
    return 0


def _check_sim_args(args: argparse.Namespace) -> None:
    if args.profile not in PROFILES:
        raise UsageError(f"--profile {args.profile!r}: choose from {', '.join(PROFILES)}")
    for name, value, lo, hi in (("--duration", args.duration, 30.0, 36000.0),
                                ("--rate", args.rate, 2.0, 1000.0),
                                ("--noise", args.noise, 0.0, 0.5)):
        if not (math.isfinite(value) and lo <= value <= hi):
            raise UsageError(f"{name} {value:g}: must lie in {lo:g}..{hi:g}")
    if not (Path(args.calibration) / "calibration.json").is_file():
        raise UsageError(f"--calibration {args.calibration}: no calibration.json there")


def cmd_sim_vehicle(args: argparse.Namespace) -> int:
    _check_sim_args(args)
    truth, profile = TRUTHS[args.truth], PROFILES[args.profile]
    twin = VehicleTwin(truth, profile, args.seed)
    t, wrench = excitation(args.duration, args.rate, args.seed)
    log = free_run(twin, t, wrench, args.noise)
    folder = Path(args.out)
    folder.mkdir(parents=True, exist_ok=True)
    _write_log(folder / "log.csv", log, [m.name for m in truth.thrusters])
    cal = os.path.relpath(Path(args.calibration).resolve(), folder.resolve())
    (folder / "vehicle.yaml").write_text(_vehicle_yaml(truth, profile.tau_s, cal), encoding="utf-8")
    out.print(f"wrote {folder}/vehicle.yaml and {folder}/log.csv ({len(t)} rows, "
              f"{args.duration:g} s of {truth.name}, noise {args.noise:g})")
    return 0


def _write_log(path: Path, log: object, names: list[str]) -> None:
    """The twin's log as rigtool identify reads it."""
    header = ["t_s", "u_mps", "v_mps", "w_mps", "p_radps", "q_radps", "r_radps", "roll_rad",
              "pitch_rad", "yaw_rad", *(f"{n}_us" for n in names)]
    rows = np.column_stack((log.t_s, log.nu, log.eta[:, 3:6], log.commands))
    with path.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows([[f"{x:.6g}" for x in row] for row in rows])


def _vehicle_yaml(truth: object, lag_s: float, calibration: str) -> str:
    """The vehicle file of the twin's truth (rigid body only: the hydrodynamics are the
    unknowns), every thruster on `calibration`."""
    ix, iy, iz = truth.inertia_kg_m2
    lines = [f"name: {json.dumps(truth.name)}", f"mass_kg: {truth.mass_kg!r}",
             f"inertia_kg_m2: [{ix!r}, {iy!r}, {iz!r}]",
             f"cob_m: [{', '.join(repr(x) for x in truth.cob_m)}]",
             f"buoyancy_n: {truth.buoyancy_n!r}",
             f"gravity_m_s2: {truth.weight_n / truth.mass_kg!r}", "thrusters:"]
    for m in truth.thrusters:
        lines += [f"  - name: {m.name}",
                  f"    position_m: [{', '.join(repr(x) for x in m.position_m)}]",
                  f"    direction: [{', '.join(repr(x) for x in m.direction)}]",
                  f"    calibration: {json.dumps(calibration)}",
                  f"    column: {m.name}_us",
                  f"    lag_s: {lag_s!r}"]
    return "\n".join(lines) + "\n"
