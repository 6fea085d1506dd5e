"""Shared helpers of the dynamics tests: step protocols through the CLI, Tyto-style step logs."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from rigtool.cli import main
from rigtool.sim.physics import ThrusterTwin
from rigtool.thruster_profiles import profile_with_overrides

PROTOCOL = """\
rigtool_protocol: 1
name: steps
simulator: {{profile: {profile}, seed: {seed}, overrides: {overrides}}}
metadata: {{propeller_diameter_m: 0.1, water_density_kg_m3: 1000}}
command: {{unit: {unit}, steps: {steps}}}
depth: {{unit: m, values: [1.0]}}
timing:
  settle: {{seconds: 0}}
  acquire: {{seconds: {hold}, rate_hz: {rate}}}
  rest_s: 0
  tare: at_start
"""
STEADY = """\
rigtool_protocol: 1
name: steady
simulator: {{profile: {profile}, seed: {seed}}}
metadata: {{propeller_diameter_m: 0.1, water_density_kg_m3: 1000}}
command: {{unit: {unit}, range: {{start: {lo}, stop: {hi}, step: {step}}}, order: up}}
depth: {{unit: m, values: [1.0]}}
timing:
  settle: {{seconds: 1.0}}
  acquire: {{samples: 200, rate_hz: 1000}}
  tare: at_start
"""
UNITS = {"can-bldc": "percent", "esc-1100-1900": "pulse_us"}
TYTO_HEADER = ["Time (s)", "ESC (µs)", "Thrust (N)", "Voltage (V)", "Current (A)",
               "Motor Optical Speed (RPM)"]
STEP_MAPPING = "rigtool_mapping: 1\nformat: steps\n"


def overrides(truth: dict) -> str:
    """A YAML flow mapping of twin overrides."""
    return "{" + ", ".join(f"{k}: {v}" for k, v in truth.items()) + "}"


def sweep_steps(tmp: Path, name: str, profile: str, steps: list, seed: int, truth: dict,
                hold: float = 2.0, rate: int = 250) -> tuple[str, Path]:
    """Sweep and calibrate a step protocol on the twin; (database, calibration folder)."""
    path = tmp / f"{name}.yaml"
    path.write_text(PROTOCOL.format(profile=profile, unit=UNITS[profile], steps=list(steps),
                                    seed=seed, overrides=overrides(truth), hold=hold,
                                    rate=rate))
    db, out = str(tmp / f"{name}.sqlite"), tmp / f"cal-{name}"
    assert main(["sweep", str(path), "--sim", "--db", db]) == 0
    assert main(["calibrate", "last", "--db", db, "--out", str(out)]) == 0
    return db, next(out.iterdir())


def sweep_steady(tmp: Path, db: str, profile: str, seed: int) -> None:
    """A short steady sweep of the same rig into `db` (for exports with --dynamics)."""
    span = {"can-bldc": (-100, 100, 10), "esc-1100-1900": (1100, 1900, 40)}[profile]
    path = tmp / "steady.yaml"
    path.write_text(STEADY.format(profile=profile, unit=UNITS[profile], seed=seed,
                                  lo=span[0], hi=span[1], step=span[2]))
    assert main(["sweep", str(path), "--sim", "--db", db]) == 0
    assert main(["calibrate", "last", "--db", db, "--out", str(tmp / "cal-steady")]) == 0


def dynamics_doc(folder: Path) -> dict | None:
    """calibration.json's `dynamics`."""
    return json.loads((folder / "calibration.json").read_text())["dynamics"]


def tyto_rows(steps: list[float], truth: dict, seed: int, hold: float = 2.0,
              rate: float = 200.0) -> list[list]:
    """A step log of the ESC twin as a Tyto stand writes it: time, ESC, thrust, voltage,
    current and (unsigned) optical speed, the command changing at known times."""
    p = profile_with_overrides("esc-1100-1900", truth)
    twin = ThrusterTwin(p, seed)
    rows, n = [], int(hold * rate)
    for k, command in enumerate(steps):
        t0 = 0.5 + k * hold
        twin.set_command(t0, command)
        t = t0 + np.arange(n) / rate
        s = twin.sample(t)
        thrust = s.ft[:, p.thrust_channel] * p.thrust_sign - p.bias_n
        rows += [[f"{t[i]:.4f}", f"{command:g}", f"{thrust[i]:.5f}", f"{s.voltage_v[i]:.4f}",
                  f"{s.current_a[i]:.4f}", f"{abs(s.speed_rpm[i]):.2f}"] for i in range(n)]
    return rows


def write_csv(path: Path, rows: list[list]) -> Path:
    """A CSV with the Tyto header."""
    with path.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh)
        writer.writerow(TYTO_HEADER)
        writer.writerows(rows)
    return path


def import_steps(tmp: Path, csv_path: Path, db: str) -> Path | None:
    """Import a step log (format steps) and calibrate it; the calibration folder."""
    mapping = tmp / "steps-mapping.yaml"
    mapping.write_text(STEP_MAPPING)
    assert main(["import", str(csv_path), "--mapping", str(mapping), "--db", db]) == 0
    out = tmp / f"cal-{csv_path.stem}"
    assert main(["calibrate", "last", "--db", db, "--out", str(out)]) == 0
    return next(out.iterdir())
