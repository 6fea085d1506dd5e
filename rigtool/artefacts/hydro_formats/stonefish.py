"""Stonefish: no block, because a Stonefish body takes no hydrodynamic derivatives.

From the source (FOLLOWS), a dynamic body's XML (ScenarioParser::ParseSolid) has only
<hydrodynamics viscous_drag="x y z" quadratic_drag="x y z"/> (SolidEntity::
SetHydrodynamicCoefficients; docs/bodies.rst, "Overriding estimated hydrodynamic
coefficients"). Those are dimensionless coefficients Cf and Cd, one per body axis, that scale
forces Stonefish integrates over the body's mesh face by face (0.5 rho Cd S v^2 and rho Cf S v,
SolidEntity::ComputeHydrodynamicForcesSubmerged and CorrectHydrodynamicForces); the same
coefficient scales the torque. Turning X_u|u| into Cd would need the areas that integration
uses (the user's mesh), and there is no input for the rotational terms K_p ... N_r|r|. Added
mass has no input at all: Stonefish computes it from a sphere, cylinder or ellipsoid fitted
to the geometry (SolidEntity::ComputeFluidDynamicsApprox; docs/theory.rst, "Added mass") and
uses the mean of the three translational terms. So rigtool writes nothing for Stonefish and
`needs` says why.
"""

from __future__ import annotations

from typing import Any

from rigtool.artefacts.hydro_formats.common import HydroOptions
from rigtool.errors import UsageError

FILE = None  # nothing is written
FOLLOWS = ("Stonefish (patrykcieslak/stonefish at b21eb8e: Library/src/core/ScenarioParser.cpp "
           "ParseSolid, Library/src/entities/SolidEntity.cpp, docs/bodies.rst, docs/theory.rst)")
REASON = ("Stonefish takes no hydrodynamic derivatives: a body's <hydrodynamics> element has "
          "only dimensionless drag coefficients (viscous_drag, quadratic_drag) that scale "
          "forces integrated over its mesh, and added mass is computed from the geometry "
          "(ScenarioParser.cpp, SolidEntity.cpp at b21eb8e); use the mesh, mass and inertia")


def needs(model: dict[str, Any], options: HydroOptions) -> list[str]:
    """Always the reason there is no Stonefish block."""
    return [REASON]


def render(model: dict[str, Any], options: HydroOptions) -> str:
    """Never renders: UsageError with the reason."""
    raise UsageError(f"stonefish: {REASON}")
