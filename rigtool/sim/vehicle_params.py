"""Published parameters of a real small ROV, the vehicle twin's truth.

Two published BlueROV2 parameter sets, both with the Heavy kit's eight T200 thrusters so every
degree of freedom is actuated (positions and directions from von Benzon et al., "An Open-Source
Benchmark Simulator: Control of a BlueROV2 Underwater Robot", JMSE 10(12), 2022):
- BLUEROV2: the standard vehicle's mass, inertia and hydrodynamic derivatives from C. J. Wu,
  "6-DoF Modelling and Control of a Remotely Operated Vehicle" (Flinders University, 2018),
  every damping term non-zero; the twin's default truth.
- BLUEROV2_HEAVY: the Heavy configuration's set from von Benzon et al. (2022), where the
  linear sway, roll and yaw damping are zero; a second, different truth.

Convention (Fossen 2011, SNAME): body axes x forward, y starboard, z down, origin at the
centre of gravity; hydrodynamic derivatives carry their sign (X_udot, X_u and X_uu are
negative for a real hull): M_A = -diag(X_udot, ...), damping force X = X_u u + X_uu u|u|.
"""

from __future__ import annotations

from dataclasses import dataclass, field

DOFS = ("surge", "sway", "heave", "roll", "pitch", "yaw")
VELOCITIES = ("u", "v", "w", "p", "q", "r")
FORCES = ("X", "Y", "Z", "K", "M", "N")


@dataclass(frozen=True)
class ThrusterMount:
    """One thruster on the hull: where it pushes (m, body axes) and which way (unit vector)."""

    name: str
    position_m: tuple[float, float, float]
    direction: tuple[float, float, float]


@dataclass(frozen=True)
class VehicleParams:
    """Rigid body and diagonal hydrodynamics of one vehicle, SNAME signs, SI units."""

    name: str
    mass_kg: float
    inertia_kg_m2: tuple[float, float, float]
    cog_m: tuple[float, float, float]
    cob_m: tuple[float, float, float]
    weight_n: float
    buoyancy_n: float
    added_mass: tuple[float, ...]  # X_udot, Y_vdot, Z_wdot, K_pdot, M_qdot, N_rdot
    linear_damping: tuple[float, ...]  # X_u, Y_v, Z_w, K_p, M_q, N_r
    quadratic_damping: tuple[float, ...]  # X_uu, Y_vv, Z_ww, K_pp, M_qq, N_rr (X_u|u| ...)
    thrusters: tuple[ThrusterMount, ...] = field(default=())


_S = 0.70710678118654757
BLUEROV2_HEAVY_THRUSTERS = (
    ThrusterMount("t1", (0.156, 0.111, 0.085), (_S, -_S, 0.0)),
    ThrusterMount("t2", (0.156, -0.111, 0.085), (_S, _S, 0.0)),
    ThrusterMount("t3", (-0.156, 0.111, 0.085), (-_S, -_S, 0.0)),
    ThrusterMount("t4", (-0.156, -0.111, 0.085), (-_S, _S, 0.0)),
    ThrusterMount("t5", (0.120, 0.218, 0.0), (0.0, 0.0, -1.0)),
    ThrusterMount("t6", (0.120, -0.218, 0.0), (0.0, 0.0, 1.0)),
    ThrusterMount("t7", (-0.120, 0.218, 0.0), (0.0, 0.0, 1.0)),
    ThrusterMount("t8", (-0.120, -0.218, 0.0), (0.0, 0.0, -1.0)),
)

BLUEROV2 = VehicleParams(
    name="BlueROV2 (Wu 2018)",
    mass_kg=11.5,
    inertia_kg_m2=(0.16, 0.16, 0.16),
    cog_m=(0.0, 0.0, 0.0),
    cob_m=(0.0, 0.0, -0.02),
    weight_n=112.8,
    buoyancy_n=114.8,
    added_mass=(-5.5, -12.7, -14.57, -0.12, -0.12, -0.12),
    linear_damping=(-4.03, -6.22, -5.18, -0.07, -0.07, -0.07),
    quadratic_damping=(-18.18, -21.66, -36.99, -1.55, -1.55, -1.55),
    thrusters=BLUEROV2_HEAVY_THRUSTERS,
)

BLUEROV2_HEAVY = VehicleParams(
    name="BlueROV2 Heavy",
    mass_kg=13.5,
    inertia_kg_m2=(0.26, 0.23, 0.37),
    cog_m=(0.0, 0.0, 0.0),
    cob_m=(0.0, 0.0, -0.01),
    weight_n=13.5 * 9.81,
    buoyancy_n=13.5 * 9.81 + 2.0,
    added_mass=(-6.36, -7.12, -18.68, -0.189, -0.135, -0.222),
    linear_damping=(-13.7, 0.0, -33.0, 0.0, -0.8, 0.0),
    quadratic_damping=(-141.0, -217.0, -190.0, -1.19, -0.47, -1.5),
    thrusters=BLUEROV2_HEAVY_THRUSTERS,
)
