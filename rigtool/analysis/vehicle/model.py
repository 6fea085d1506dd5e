"""The vehicle model identification fits: Fossen's equations with diagonal added mass and
damping, simulated for many segments (and many parameter sets) at once.

Parameters theta (18, SNAME signs): added mass X_udot..N_rdot, linear damping X_u..N_r,
quadratic damping X_uu..N_rr (X_u|u| ...). The rigid body (mass, inertia, weight, buoyancy
and their centres) is known from the vehicle file; the attitude is taken from the log for
the restoring forces, so only velocities are simulated.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

ADDED = ("X_udot", "Y_vdot", "Z_wdot", "K_pdot", "M_qdot", "N_rdot")
LINEAR = ("X_u", "Y_v", "Z_w", "K_p", "M_q", "N_r")
QUADRATIC = ("X_uu", "Y_vv", "Z_ww", "K_pp", "M_qq", "N_rr")
NAMES = ADDED + LINEAR + QUADRATIC
DOFS = ("surge", "sway", "heave", "roll", "pitch", "yaw")
VELOCITY = ("u", "v", "w", "p", "q", "r")
UNITS = ("m/s", "m/s", "m/s", "rad/s", "rad/s", "rad/s")

# (C_A nu)_i = sum_j G_ij(nu) a_j, a = -added mass: (row i, column j, sign, velocity pair).
_CA_TERMS = ((0, 2, 1, 2, 4), (0, 1, -1, 1, 5), (1, 0, 1, 0, 5), (1, 2, -1, 2, 3),
             (2, 1, 1, 1, 3), (2, 0, -1, 0, 4), (3, 2, 1, 1, 2), (3, 1, -1, 1, 2),
             (3, 5, 1, 4, 5), (3, 4, -1, 4, 5), (4, 0, 1, 2, 0), (4, 2, -1, 2, 0),
             (4, 3, 1, 5, 3), (4, 5, -1, 5, 3), (5, 1, 1, 0, 1), (5, 0, -1, 0, 1),
             (5, 4, 1, 3, 4), (5, 3, -1, 3, 4))


@dataclass(frozen=True)
class RigidBody:
    """What the vehicle file states: mass, inertia, weight and buoyancy with their centres."""

    mass_kg: float
    inertia_kg_m2: tuple[float, float, float]
    cob_m: tuple[float, float, float]
    weight_n: float
    buoyancy_n: float

    @property
    def diagonal(self) -> np.ndarray:
        """The rigid-body mass matrix's diagonal (origin at the centre of gravity)."""
        return np.array([self.mass_kg] * 3 + list(self.inertia_kg_m2))


def coriolis_rigid(body: RigidBody, nu: np.ndarray) -> np.ndarray:
    """C_RB(nu) nu for velocities of shape (..., 6)."""
    m, (ix, iy, iz) = body.mass_kg, body.inertia_kg_m2
    u, v, w, p, q, r = np.moveaxis(nu, -1, 0)
    return np.stack((m * (q * w - r * v), m * (r * u - p * w), m * (p * v - q * u),
                     (iz - iy) * q * r, (ix - iz) * r * p, (iy - ix) * p * q), axis=-1)


def coriolis_added_matrix(nu: np.ndarray) -> np.ndarray:
    """G(nu) of shape (..., 6, 6) with (C_A nu)_i = sum_j G_ij a_j, a = -added mass."""
    g = np.zeros((*nu.shape[:-1], 6, 6))
    for i, j, sign, k, m in _CA_TERMS:
        g[..., i, j] += sign * nu[..., k] * nu[..., m]
    return g


def coriolis_added(nu: np.ndarray, a: np.ndarray) -> np.ndarray:
    """C_A(nu) nu for velocities (..., 6) and added masses a = -X_udot... of shape (..., 6)."""
    u, v, w, p, q, r = np.moveaxis(nu, -1, 0)
    a1, a2, a3, a4, a5, a6 = np.moveaxis(a, -1, 0)
    return np.stack((a3 * w * q - a2 * v * r, a1 * u * r - a3 * w * p, a2 * v * p - a1 * u * q,
                     (a3 - a2) * v * w + (a6 - a5) * q * r, (a1 - a3) * w * u + (a4 - a6) * r * p,
                     (a2 - a1) * u * v + (a5 - a4) * p * q), axis=-1)


def restoring(body: RigidBody, attitude: np.ndarray) -> np.ndarray:
    """g(eta) for roll and pitch of shape (..., 2): weight at the origin, buoyancy at cob."""
    phi, theta = attitude[..., 0], attitude[..., 1]
    w, b = body.weight_n, body.buoyancy_n
    dx, dy, dz = -np.sin(theta), np.cos(theta) * np.sin(phi), np.cos(theta) * np.cos(phi)
    xb, yb, zb = body.cob_m
    mx, my, mz = -yb * b, -zb * b, -xb * b
    return np.stack((-(w - b) * dx, -(w - b) * dy, -(w - b) * dz, -(mx * dz - my * dy),
                     -(my * dx - mz * dz), -(mz * dy - mx * dx)), axis=-1)


def known_forces(body: RigidBody, tau: np.ndarray, nu: np.ndarray, nu_dot: np.ndarray,
                 attitude: np.ndarray) -> np.ndarray:
    """tau - M_RB nu' - C_RB nu - g: what the hydrodynamic terms must balance."""
    return tau - body.diagonal * nu_dot - coriolis_rigid(body, nu) - restoring(body, attitude)


def regressors(nu: np.ndarray, nu_dot: np.ndarray) -> np.ndarray:
    """Phi of shape (N, 6, 18): M_A nu' + C_A nu + D nu = Phi @ theta (equation error)."""
    phi = np.zeros((nu.shape[0], 6, 18))
    phi[:, :, :6] = -coriolis_added_matrix(nu)
    idx = np.arange(6)
    phi[:, idx, idx] -= nu_dot
    phi[:, idx, 6 + idx] = -nu
    phi[:, idx, 12 + idx] = -nu * np.abs(nu)
    return phi


@dataclass(frozen=True)
class Segments:
    """Equal-length stretches of logs on one time step, stacked: (S, L, ...)."""

    dt_s: float
    nu: np.ndarray  # measured velocities (S, L, 6)
    smooth: np.ndarray  # smoothed velocities, the exogenous inputs and initial states
    tau: np.ndarray  # thruster wrench (S, L, 6), held over each step
    attitude: np.ndarray  # (S, L, 2)
    log: np.ndarray  # which log each segment came from (S,)
    start_s: np.ndarray  # start time of each segment in its log (S,)

    def take(self, index: np.ndarray) -> Segments:
        """The segments at `index`."""
        return Segments(self.dt_s, self.nu[index], self.smooth[index], self.tau[index],
                        self.attitude[index], self.log[index], self.start_s[index])

    def __len__(self) -> int:
        return self.nu.shape[0]


def _accel(body: RigidBody, theta: np.ndarray, nu: np.ndarray, cross: np.ndarray,
           cross_a: np.ndarray, tau: np.ndarray, attitude: np.ndarray) -> np.ndarray:
    """nu' for parameter sets theta (P, 1, 18), own states nu (P, S, 6) in the damping and
    states `cross` and added masses `cross_a` in the Coriolis terms (row i of which never
    holds velocity i nor added mass i)."""
    a = -theta[..., :6]
    damping = (theta[..., 6:12] + theta[..., 12:] * np.abs(nu)) * nu
    rhs = (tau - coriolis_rigid(body, cross) - coriolis_added(cross, cross_a) + damping
           - restoring(body, attitude))
    return rhs / (body.diagonal + a)


def _attitude_rate(attitude: np.ndarray, rates: np.ndarray) -> np.ndarray:
    """Roll and pitch rates from body rates p, q, r (ZYX Euler angles)."""
    phi, theta = attitude[..., 0], attitude[..., 1]
    p, q, r = rates[..., 0], rates[..., 1], rates[..., 2]
    s, c = np.sin(phi), np.cos(phi)
    return np.stack((p + (q * s + r * c) * np.tan(theta), q * c - r * s), axis=-1)


def simulate(body: RigidBody, theta: np.ndarray, seg: Segments, free: np.ndarray,
             coupled: bool, fixed: np.ndarray | None = None) -> np.ndarray:
    """Velocities (P, S, L, 6) of parameter sets theta (P, 18) over every segment, from each
    segment's smoothed first state; roll and pitch are simulated too, from the logged ones at
    the start, for the restoring forces. DOFs not `free` (bool, 6) follow the smoothed log.
    Coupled: the free DOFs' Coriolis terms use the simulated velocities (the six-DOF model);
    else the logged ones and the added masses of `fixed` (18), so each DOF is simulated on
    its own with its own parameters only (the per-DOF model)."""
    theta = np.atleast_2d(theta)[:, None, :]
    cross_a = -(theta if coupled or fixed is None else np.asarray(fixed)[None, None])[..., :6]
    n_sets, (n_seg, length, _) = theta.shape[0], seg.nu.shape
    out = np.empty((n_sets, n_seg, length, 6))
    state = np.broadcast_to(seg.smooth[:, 0], (n_sets, n_seg, 6)).copy()
    angles = np.broadcast_to(seg.attitude[:, 0], (n_sets, n_seg, 2)).copy()
    out[:, :, 0] = state
    h = seg.dt_s
    for k in range(length - 1):
        ends = seg.smooth[:, k], 0.5 * (seg.smooth[:, k] + seg.smooth[:, k + 1]), seg.smooth[:, k + 1]

        def rate(x: np.ndarray, att: np.ndarray, at: int, tau: np.ndarray = seg.tau[:, k],
                 ends: tuple = ends) -> tuple[np.ndarray, np.ndarray]:
            x = np.where(free, x, ends[at])
            cross = x if coupled else np.broadcast_to(ends[at], x.shape)
            own_rates = np.where(free[3:], x[..., 3:], ends[at][..., 3:])
            return (np.where(free, _accel(body, theta, x, cross, cross_a, tau, att), 0.0),
                    _attitude_rate(att, own_rates))

        k1, a1 = rate(state, angles, 0)
        k2, a2 = rate(state + 0.5 * h * k1, angles + 0.5 * h * a1, 1)
        k3, a3 = rate(state + 0.5 * h * k2, angles + 0.5 * h * a2, 1)
        k4, a4 = rate(state + h * k3, angles + h * a3, 2)
        state = state + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        angles = angles + h / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
        out[:, :, k + 1] = np.where(free, state, seg.smooth[:, k + 1])
    return out
