"""The captive twin's physics: a held vehicle in a flow (or towed), pure and clock-injected.

A vehicle held at yaw angle psi (or angle of attack alpha) in a flow of speed U sees the
relative velocity u = U cos psi, v = U sin psi (attack: w = U sin alpha) in its body axes and
feels, per axis, the damping force of Fossen's model: X = X_u u + X_uu u|u|, and so on
(rigtool/sim/vehicle_params.py holds the truth). With diagonal damping and no rotation the
moments K, M, N are zero. The carriage (or pump) reaches a new speed with a first-order lag,
and the flow is unsteady: each force fluctuates by `noise_frac` of itself (plus a floor),
as an AR(1) process with time constant `TURBULENCE_TAU_S`, so a point's mean keeps a scatter
that averaging over the point does not remove. Callers pass times; all randomness comes
from one seeded generator.
"""

from __future__ import annotations

import math

import numpy as np

from rigtool.sim.vehicle_params import BLUEROV2, BLUEROV2_HEAVY, VehicleParams

VEHICLES = {"bluerov2": BLUEROV2, "bluerov2-heavy": BLUEROV2_HEAVY}
SPEED_TAU_S = 0.5  # the carriage's (or pump's) first-order speed lag
TURBULENCE_TAU_S = 0.3  # correlation time of the flow's force fluctuations
NOISE_FLOOR_N = 0.05  # force fluctuation at rest and at any speed, N (N m for moments)


def body_velocity(speed_mps: float | np.ndarray, angle_deg: float, angle: str
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(u, v, w) of the flow relative to the held body: yaw turns it in x-y, attack in x-z."""
    rad = math.radians(angle_deg)
    u = np.asarray(speed_mps, dtype=float) * math.cos(rad)
    across = np.asarray(speed_mps, dtype=float) * math.sin(rad)
    zero = np.zeros_like(u)
    return (u, across, zero) if angle == "yaw" else (u, zero, across)


def damping_loads(vehicle: VehicleParams, speed_mps: float | np.ndarray, angle_deg: float,
                  angle: str) -> np.ndarray:
    """Body-frame X, Y, Z, K, M, N (N, N m), shape (..., 6): tau_i = D_i nu_i + D_ii nu_i |nu_i|
    per axis (Fossen 2011, diagonal damping), rotation rates zero."""
    u, v, w = body_velocity(speed_mps, angle_deg, angle)
    out = np.zeros((*np.shape(u), 6))
    for i, nu in enumerate((u, v, w)):
        out[..., i] = vehicle.linear_damping[i] * nu + vehicle.quadratic_damping[i] * nu * np.abs(nu)
    return out


class CaptiveFlow:
    """Flow speed and angle over time, and the loads they put on the held vehicle."""

    def __init__(self, vehicle: VehicleParams, *, angle: str = "yaw", noise_frac: float = 0.03,
                 seed: int = 0, t0: float = 0.0) -> None:
        self.vehicle = vehicle
        self.angle = angle
        self.noise_frac = noise_frac
        self._rng = np.random.default_rng([seed, 0xF10])
        self._t = t0
        self._speed_from = 0.0  # speed at self._t_set, heading for self.target_mps
        self._t_set = t0
        self.target_mps = 0.0
        self.angle_deg = 0.0
        self._ar = np.zeros(6)  # the fluctuation's state, in units of its standard deviation

    def speed_at(self, t: np.ndarray | float) -> np.ndarray:
        """The flow speed at times `t` (the lag towards the target since it was set)."""
        dt = np.maximum(np.asarray(t, dtype=float) - self._t_set, 0.0)
        return self.target_mps + (self._speed_from - self.target_mps) * np.exp(-dt / SPEED_TAU_S)

    def set_speed(self, t: float, speed_mps: float) -> None:
        """Aim for `speed_mps` from time `t` on."""
        self._speed_from = float(self.speed_at(t))
        self._t_set = t
        self.target_mps = float(speed_mps)

    def set_angle(self, angle_deg: float) -> None:
        """Turn the held vehicle to `angle_deg` (the stage turns while the flow is at rest)."""
        self.angle_deg = float(angle_deg)

    def settled_at(self, t: float, tolerance_mps: float = 1e-5) -> float:
        """The time from which the speed is within `tolerance_mps` of its target."""
        gap = abs(self._speed_from - self.target_mps)
        if gap <= tolerance_mps:
            return max(t, self._t_set)
        return max(t, self._t_set + SPEED_TAU_S * math.log(gap / tolerance_mps))

    def loads(self, t: np.ndarray) -> np.ndarray:
        """The six loads on the body at increasing times `t` (n, 6), fluctuations included."""
        t = np.asarray(t, dtype=float)
        mean = damping_loads(self.vehicle, self.speed_at(t), self.angle_deg, self.angle)
        sd = np.hypot(self.noise_frac * np.abs(mean), NOISE_FLOOR_N)
        return mean + sd * self._fluctuation(t)

    def _fluctuation(self, t: np.ndarray) -> np.ndarray:
        """Unit-variance AR(1) noise per channel at times `t` (continuing from the last call)."""
        from scipy.signal import lfilter

        if t.size == 0:
            return np.empty((0, 6))
        dt = np.diff(t, prepend=self._t)
        rho = np.exp(-np.maximum(dt, 0.0) / TURBULENCE_TAU_S)
        shock = self._rng.standard_normal((t.size, 6)) * np.sqrt(1.0 - rho**2)[:, None]
        out = np.empty((t.size, 6))
        out[0] = rho[0] * self._ar + shock[0]
        if t.size > 1:  # evenly spaced samples after the first: one filter per channel
            r = float(np.mean(rho[1:]))
            out[1:], _ = lfilter([1.0], [1.0, -r], shock[1:], axis=0, zi=r * out[0][None, :])
        self._ar = out[-1].copy()
        self._t = float(t[-1])
        return out
