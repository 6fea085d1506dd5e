"""The documents `rigtool identify` writes: the vehicle model (a plain JSON document that
the simulator blocks are made from) and identification.json (how it was found)."""

from __future__ import annotations

from typing import Any

import numpy as np

from rigtool.analysis.vehicle.identify import Identification
from rigtool.analysis.vehicle.model import ADDED, LINEAR, QUADRATIC
from rigtool.artefacts.vehicle_model import FORMAT, SCHEMA_VERSION
from rigtool.version import __version__

IDENTIFICATION_FILE = "identification.json"


def _parameter(p: Any) -> dict:
    """One parameter as {value, ci95, reason}."""
    ci = None if p.low is None or p.value is None else [p.low, p.high]
    return {"value": p.value, "ci95": ci, "reason": p.reason}


def model_document(rigid: dict, ident: Identification) -> dict:
    """vehicle_model.json (docs/vehicle-formats.md): the vehicle file's rigid body and the
    identified hydrodynamics, Fossen's SNAME convention in body axes FRD."""
    by_name = {p.name: p for p in ident.parameters}
    return {
        "format": FORMAT,
        "schema_version": SCHEMA_VERSION,
        "name": rigid["name"],
        "frame": "FRD",
        "rigid_body": {k: rigid[k] for k in ("mass_kg", "inertia_kg_m2", "cog_m", "cob_m",
                                             "weight_n", "buoyancy_n", "water_density_kg_m3",
                                             "gravity_m_s2")},
        "hydrodynamics": {
            group: {n: _parameter(by_name[n]) for n in names}
            for group, names in (("added_mass", ADDED), ("linear_damping", LINEAR),
                                 ("quadratic_damping", QUADRATIC))},
    }


def identification_document(ident: Identification, sources: list[dict]) -> dict:
    """identification.json: method, structures, estimates of every method, held-out errors."""
    return {
        "rigtool_version": __version__,
        "method": ident.method,
        "dofs": ident.dofs,
        "logs": sources,
        "time_step_s": ident.dt_s,
        "segments": {"fitted": ident.segments_fitted, "held_out": ident.segments_held_out},
        "structures": ident.structures,
        "structure_held_out_sse": ident.structure_errors,
        "estimates": ident.estimates,
        "global_vs_least_squares": None if ident.global_agreement is None else {
            "largest_relative_difference": ident.global_agreement,
            "meaning": "the largest |global - least squares| / |least squares| over the free "
                       "parameters, both minimising the per-DOF output error on the same "
                       "segments"},
        "held_out": [{"dof": h.dof, "rms": h.rms, "range": h.range, "percent_of_range": h.percent}
                     for h in ident.held_out],
        "parameters": {p.name: _parameter(p) for p in ident.parameters},
        "notes": ident.notes,
    }


def rigid_summary(name: str, mass_kg: float, inertia: tuple[float, ...], cob_m: tuple,
                  weight_n: float, buoyancy_n: float, density: float, gravity: float) -> dict:
    """The rigid body as vehicle_model.json states it (inertia as a 3 x 3 matrix)."""
    return {"name": name, "mass_kg": mass_kg,
            "inertia_kg_m2": np.diag(inertia).tolist(), "cog_m": [0.0, 0.0, 0.0],
            "cob_m": list(cob_m), "weight_n": weight_n, "buoyancy_n": buoyancy_n,
            "water_density_kg_m3": density, "gravity_m_s2": gravity}
