"""The vehicle twin: a six-DOF vehicle (Fossen's equations) driven by rigtool's thruster twins.

It makes free-running logs from known truth, so vehicle identification can be checked: the
body velocities and attitude it logs carry settable noise (a fraction of each channel's
spread), its thrusters follow their twin's command map and speed lag, and its commands come
from an excitation design that moves every degree of freedom both ways. Pure and seeded:
the same seed gives the same log.

Equations (body axes FRD, origin at the centre of gravity, Euler angles ZYX):
    (M_RB + M_A) nu' + C_RB(nu) nu + C_A(nu) nu + D(nu) nu + g(eta) = B f
with M_A = -diag(added_mass), D(nu) nu = -(linear + quadratic |nu|) nu, f the thrusts.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rigtool.sim.physics import ThrusterTwin
from rigtool.sim.vehicle_params import VehicleParams
from rigtool.thruster_profiles import ThrusterProfile

GRAVITY_M_S2 = 9.81
ATTITUDE_KP = 10.0  # N m/rad: the pilot's roll and pitch hold (loose: roll and pitch still swing)
ATTITUDE_KD = 0.3  # N m s/rad
_SUBSTEP_S = 0.02  # RK4 step: a seventh of the T200 twin's speed lag, a tenth of a second of roll


def allocation(params: VehicleParams) -> np.ndarray:
    """The 6 x n matrix taking thrusts (N) to the body wrench (forces N, moments N m)."""
    cols = []
    for t in params.thrusters:
        d = np.asarray(t.direction, dtype=float)
        cols.append(np.concatenate((d, np.cross(np.asarray(t.position_m, dtype=float), d))))
    return np.array(cols).T


def _rotation(phi: float, theta: float, psi: float) -> np.ndarray:
    """Body-to-NED rotation (ZYX Euler angles)."""
    cf, sf, ct, st, cp, sp = (np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta),
                              np.cos(psi), np.sin(psi))
    return np.array([[cp * ct, -sp * cf + cp * st * sf, sp * sf + cp * cf * st],
                     [sp * ct, cp * cf + sf * st * sp, -cp * sf + st * sp * cf],
                     [-st, ct * sf, ct * cf]])


def _euler_rates(phi: float, theta: float) -> np.ndarray:
    """Matrix taking body rates (p, q, r) to Euler angle rates."""
    cf, sf, ct, tt = np.cos(phi), np.sin(phi), np.cos(theta), np.tan(theta)
    return np.array([[1.0, sf * tt, cf * tt], [0.0, cf, -sf], [0.0, sf / ct, cf / ct]])


class VehicleTwin:
    """A vehicle of `params` whose thrusters are all thruster twins of `profile`."""

    def __init__(self, params: VehicleParams, profile: ThrusterProfile, seed: int,
                 gravity_m_s2: float = GRAVITY_M_S2) -> None:
        self.params, self.profile, self.g = params, profile, gravity_m_s2
        self._rng = np.random.default_rng(seed)
        self._thruster = ThrusterTwin(profile, seed)
        self.B = allocation(params)
        rb = np.diag([params.mass_kg] * 3 + list(params.inertia_kg_m2))
        self.M = rb - np.diag(params.added_mass)
        self._M_inv_diag = 1.0 / np.diag(self.M)  # M is diagonal: origin at the centre of gravity
        self._a = tuple(-x for x in params.added_mass)
        self._lin, self._quad = params.linear_damping, params.quadratic_damping
        self._cp = (profile.cp_forward, profile.cp_reverse)
        grid = np.linspace(profile.command_min, profile.command_max, 1601)
        table = self.thrusts_n(self.target_speeds_rpm(grid))
        branches = []
        for part in (table > 0, table < 0):
            order = np.argsort(table[part])
            branches.append((table[part][order], grid[part][order]))
        self.map_table = tuple(branches)  # (thrusts, commands) forward, then reverse

    def target_speeds_rpm(self, commands: np.ndarray) -> np.ndarray:
        """Each thruster's steady speed under its command."""
        return np.array([self._thruster.target_speed_rpm(
            min(max(float(c), self.profile.command_min), self.profile.command_max))
            for c in commands])

    def thrusts_n(self, speeds_rpm: np.ndarray) -> np.ndarray:
        """Thrust of each thruster at its speed (the twin's law, forward and reverse)."""
        n = np.asarray(speeds_rpm, dtype=float)
        return np.where(n >= 0, self._cp[0], self._cp[1]) * n * np.abs(n)

    def restoring(self, phi: float, theta: float) -> tuple[float, ...]:
        """g(eta): weight at the centre of gravity, buoyancy at the centre of buoyancy."""
        p = self.params
        w, b = p.weight_n, p.buoyancy_n
        dx, dy, dz = -np.sin(theta), np.cos(theta) * np.sin(phi), np.cos(theta) * np.cos(phi)
        (xg, yg, zg), (xb, yb, zb) = p.cog_m, p.cob_m
        mx, my, mz = (yg * w - yb * b, zg * w - zb * b, xg * w - xb * b)  # arms times forces
        return (-(w - b) * dx, -(w - b) * dy, -(w - b) * dz,
                -(mx * dz - my * dy), -(my * dx - mz * dz), -(mz * dy - mx * dx))

    def accelerations(self, nu: np.ndarray, eta: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """nu' from Fossen's equations at body velocities nu, pose eta and wrench tau."""
        return self._M_inv_diag * self._forces(list(nu), float(eta[3]), float(eta[4]), list(tau))

    def _forces(self, nu: list, phi: float, theta: float, tau: list) -> np.ndarray:
        """tau - C_RB nu - C_A nu - D nu - g, in plain floats (the twin's inner loop)."""
        u, v, w, p, q, r = nu
        m, (ix, iy, iz) = self.params.mass_kg, self.params.inertia_kg_m2
        a1, a2, a3, a4, a5, a6 = self._a
        coriolis = (m * (q * w - r * v) + a3 * w * q - a2 * v * r,
                    m * (r * u - p * w) + a1 * u * r - a3 * w * p,
                    m * (p * v - q * u) + a2 * v * p - a1 * u * q,
                    (iz - iy) * q * r + (a3 - a2) * v * w + (a6 - a5) * q * r,
                    (ix - iz) * r * p + (a1 - a3) * w * u + (a4 - a6) * r * p,
                    (iy - ix) * p * q + (a2 - a1) * u * v + (a5 - a4) * p * q)
        g = self.restoring(phi, theta)
        return np.array([tau[i] - coriolis[i] + (self._lin[i] + self._quad[i] * abs(x)) * x - g[i]
                         for i, x in enumerate(nu)])

    def _derivative(self, state: np.ndarray, speeds_target: np.ndarray) -> np.ndarray:
        """d/dt of [eta (6), nu (6), thruster speeds]."""
        eta, nu, n = state[:6], state[6:12], state[12:]
        tau = self.B @ self.thrusts_n(n)
        d_eta = np.concatenate((_rotation(*eta[3:6]) @ nu[:3], _euler_rates(eta[3], eta[4]) @ nu[3:]))
        d_n = (speeds_target - n) / self.profile.tau_s
        return np.concatenate((d_eta, self.accelerations(nu, eta, tau), d_n))

    def run(self, t_s: np.ndarray, wrench: np.ndarray) -> tuple[np.ndarray, ...]:
        """Noise-free (eta, nu, commands) at times `t_s` (from 0, increasing) under the
        demanded body `wrench` (N x 6), each held from its time to the next. The pilot holds
        roll and pitch (a PD term on the logged attitude, as an ROV's autopilot does), and
        turns each demand into thruster commands through the allocation and the twin's map."""
        state = np.zeros(12 + self.B.shape[1])
        etas, nus = np.empty((len(t_s), 6)), np.empty((len(t_s), 6))
        commands = np.empty((len(t_s), self.B.shape[1]))
        pinv = np.linalg.pinv(self.B)
        now = float(t_s[0])
        for i, t in enumerate(t_s):
            if i:
                target = self.target_speeds_rpm(commands[i - 1])
                while t - now > 1e-12:
                    h = min(_SUBSTEP_S, t - now)
                    k1 = self._derivative(state, target)
                    k2 = self._derivative(state + h / 2 * k1, target)
                    k3 = self._derivative(state + h / 2 * k2, target)
                    k4 = self._derivative(state + h * k3, target)
                    state = state + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
                    now += h
            etas[i], nus[i] = state[:6], state[6:12]
            demand = wrench[i].copy()
            demand[3:5] -= ATTITUDE_KP * state[3:5] + ATTITUDE_KD * state[9:11]
            commands[i] = _commands_for(self, pinv @ demand)
        return etas, nus, commands

    def noisy(self, values: np.ndarray, noise_frac: float) -> np.ndarray:
        """`values` with white noise of `noise_frac` times each column's standard deviation."""
        spread = values.std(axis=0)
        return values + self._rng.standard_normal(values.shape) * noise_frac * spread


@dataclass(frozen=True)
class FreeRunLog:
    """A free-running log of the twin: what a DVL/IMU would give, and the truth behind it."""

    t_s: np.ndarray
    commands: np.ndarray  # N x thrusters, the command unit of the thruster profile
    nu: np.ndarray  # measured body velocities u v w (m/s), p q r (rad/s)
    eta: np.ndarray  # measured x y z (m, NED) and roll pitch yaw (rad)
    nu_true: np.ndarray
    eta_true: np.ndarray


def excitation(duration_s: float, rate_hz: float, seed: int,
               dofs: tuple[int, ...] = (0, 1, 2, 3, 4, 5),
               one_way: tuple[int, ...] = ()) -> tuple[np.ndarray, np.ndarray]:
    """(t_s, wrench): held random wrench demands on `dofs`, each both ways (only forward on
    `one_way`), 1.5-6 s per level."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    peak = np.array([35.0, 35.0, 35.0, 3.0, 3.0, 2.5])
    wrench = np.zeros((len(t), 6))
    start = 0.0
    while start < duration_s:
        hold = rng.uniform(1.5, 6.0)
        level = np.zeros(6)
        for d in rng.choice(dofs, size=rng.integers(1, min(3, len(dofs)) + 1), replace=False):
            sign = 1.0 if d in one_way else rng.choice((-1.0, 1.0))
            level[d] = peak[d] * rng.uniform(0.2, 1.0) * sign
        wrench[(t >= start) & (t < start + hold)] = level
        start += hold
    return t, wrench


def _commands_for(twin: VehicleTwin, thrusts: np.ndarray) -> np.ndarray:
    """The command giving each steady thrust, from the twin's table of its map."""
    (fwd_f, fwd_c), (rev_f, rev_c) = twin.map_table
    out = np.full(thrusts.shape, twin.profile.neutral)
    out = np.where(thrusts > 0, np.interp(thrusts, fwd_f, fwd_c), out)
    return np.where(thrusts < 0, np.interp(thrusts, rev_f, rev_c), out)


def free_run(twin: VehicleTwin, t_s: np.ndarray, wrench: np.ndarray,
             noise_frac: float) -> FreeRunLog:
    """Fly the demanded `wrench` and log the motion with `noise_frac` noise on every channel."""
    eta, nu, commands = twin.run(t_s, wrench)
    return FreeRunLog(t_s, commands, twin.noisy(nu, noise_frac), twin.noisy(eta, noise_frac),
                      nu, eta)
