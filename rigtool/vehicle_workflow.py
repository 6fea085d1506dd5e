"""`rigtool identify`: free-running logs + the vehicle file + thruster calibrations -> the
vehicle's hydrodynamic model, identification.json and an HTML report in one folder."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rigtool.analysis.vehicle.identify import Identification, identify
from rigtool.analysis.vehicle.model import DOFS, RigidBody
from rigtool.analysis.vehicle.segments import LogInput
from rigtool.artefacts.hydro_formats import HYDRO_FORMATS, HydroOptions
from rigtool.artefacts.vehicle_identification import (
    IDENTIFICATION_FILE,
    identification_document,
    model_document,
    rigid_summary,
)
from rigtool.artefacts.vehicle_model import FILE as MODEL_FILE
from rigtool.artefacts.vehicle_model import validate_model
from rigtool.artefacts.write import json_text, write_all
from rigtool.errors import UsageError
from rigtool.importers.vehicle_log import VehicleLog, read_vehicle_log, split_at_gaps
from rigtool.progress_hook import ProgressHook, no_progress
from rigtool.report.vehicle_html import REPORT_FILE, render_identification
from rigtool.vehicle_file import Vehicle


@dataclass(frozen=True)
class ThrusterInput:
    """One thruster's calibration as identification needs it: steady thrust (N) of a command
    (NaN outside the calibrated commands) and the lag from command to thrust."""

    thrust: Callable[[np.ndarray], np.ndarray]
    lag_s: float
    source: str


def allocation(vehicle: Vehicle) -> np.ndarray:
    """The 6 x n matrix taking thrusts to the body wrench (forces, moments about the origin)."""
    cols = [np.concatenate((t.direction, np.cross(t.position_m, t.direction)))
            for t in vehicle.thrusters]
    return np.array(cols).T


def parse_dofs(text: str | None) -> list[int]:
    """`surge,heave` -> DOF indices; all six when None."""
    if text is None:
        return list(range(6))
    names = [x.strip() for x in text.split(",") if x.strip()]
    unknown = [n for n in names if n not in DOFS]
    if unknown or not names:
        raise UsageError(f"--dofs: unknown {', '.join(unknown) or '(none given)'}; choose from "
                         f"{', '.join(DOFS)}")
    return sorted({DOFS.index(n) for n in names})


def _log_inputs(path: Path, vehicle: Vehicle, maps: dict[str, ThrusterInput]
                ) -> tuple[list[LogInput], dict]:
    """Read one log (cut at its time gaps) and turn its commands into thrusts; refuse
    commands outside a calibration."""
    whole = read_vehicle_log(path, [t.log_column for t in vehicle.thrusters])
    parts = split_at_gaps(whole)
    inputs = [_thrusts(path, part, vehicle, maps) for part in parts]
    notes = whole.notes + [n for part in parts[1:] for n in part.notes] if len(parts) > 1 \
        else whole.notes
    info = {"file": str(path), "rows": len(whole.t_s), "skipped_rows": whole.skipped_rows,
            "duration_s": float(sum(p.t_s[-1] for p in parts)), "parts": len(parts),
            "notes": notes}
    return inputs, info


def _thrusts(path: Path, log: VehicleLog, vehicle: Vehicle, maps: dict[str, ThrusterInput]
             ) -> LogInput:
    """One log part with each thruster's command turned into its thrust."""
    thrusts = np.empty_like(log.commands)
    for k, t in enumerate(vehicle.thrusters):
        thrusts[:, k] = maps[t.name].thrust(log.commands[:, k])
        bad = np.flatnonzero(~np.isfinite(thrusts[:, k]))
        if bad.size:
            raise UsageError(f"{path}: {bad.size} commands of {t.log_column} (first "
                             f"{log.commands[bad[0], k]:g} at t = {log.t_s[bad[0]]:g} s) lie "
                             f"outside the commands calibrated in {maps[t.name].source}")
    lags = np.array([maps[t.name].lag_s for t in vehicle.thrusters])
    return LogInput(str(path), log.t_s, log.nu, log.attitude, thrusts, lags)


SIMULATOR_BLOCKS = ("gz-hydrodynamics", "uuv-fossen")


def _blocks(model: dict, options: HydroOptions, out_dir: Path) -> tuple[dict, list[str]]:
    """The simulator blocks the model can fill, and a note for each it cannot."""
    texts, notes = {}, []
    for name in SIMULATOR_BLOCKS:
        fmt = HYDRO_FORMATS[name]
        missing = fmt.needs(model, options)
        if missing:
            notes.append(f"{name} block not written: {'; '.join(missing)}")
        else:
            texts[out_dir / fmt.FILE] = fmt.render(model, options)
    return texts, notes


def identify_vehicle(vehicle: Vehicle, logs: list[Path], maps: dict[str, ThrusterInput],
                     out_dir: Path, method: str = "nls", dofs: list[int] | None = None,
                     seed: int = 1, options: HydroOptions | None = None,
                     progress: ProgressHook = no_progress) -> tuple[Identification, list[Path]]:
    """Identify and write vehicle_model.json, identification.json, the report and the
    simulator blocks the model fills (gz-sim Hydrodynamics, uuv_simulator HMFossen); the
    fits reported to `progress`."""
    read = [_log_inputs(Path(p), vehicle, maps) for p in logs]
    inputs = [part for parts, _ in read for part in parts]
    sources = [info for _, info in read]
    body = RigidBody(vehicle.mass_kg, vehicle.inertia_kg_m2, vehicle.cob_m, vehicle.weight_n,
                     vehicle.buoyancy_n)
    ident = identify(list(inputs), allocation(vehicle), body, dofs or list(range(6)), method,
                     seed, progress)
    notes = [n for s in sources for n in s["notes"]]
    no_lag = [t.name for t in vehicle.thrusters if maps[t.name].lag_s == 0.0]
    if no_lag:
        notes.append(f"no thrust lag known for {', '.join(no_lag)} (give lag_s in the vehicle "
                     "file, or calibrate a step-response run): thrust taken as steady at each "
                     "command")
    rigid = rigid_summary(vehicle.name, vehicle.mass_kg, vehicle.inertia_kg_m2, vehicle.cob_m,
                          vehicle.weight_n, vehicle.buoyancy_n, vehicle.water_density_kg_m3,
                          vehicle.gravity_m_s2)
    model = validate_model(model_document(rigid, ident), MODEL_FILE)
    blocks, block_notes = _blocks(model, options or HydroOptions(link="base_link"), out_dir)
    ident = Identification(**{**ident.__dict__, "notes": ident.notes + notes + block_notes})
    texts = {
        **blocks,
        out_dir / MODEL_FILE: json_text(model, digits=None),
        out_dir / IDENTIFICATION_FILE: json_text(identification_document(ident, list(sources))),
        out_dir / REPORT_FILE: render_identification(ident, vehicle.name),
    }
    out_dir.mkdir(parents=True, exist_ok=True)
    return ident, write_all(texts)
