"""Axis mapping for a mounted six-axis F/T sensor: pure functions on (n, 6) arrays.

A sensor reports the wrench (Fx, Fy, Fz, Tx, Ty, Tz) acting at its own origin, in its
own axes. When the thruster axis does not line up with one sensor axis, or torques are
wanted about the propeller centre, re-express the wrench with `wrench_transform`:

    M = wrench_transform(rotation_deg("z", 90), offset_m=(0.12, 0, 0))
    ft_thruster = apply_transform(ft_sensor, M)

`thrust_along(ft, axis)` projects the force on one unit vector (a tilted mount).
"""

from __future__ import annotations

import numpy as np

_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


def _vector(v: str | np.ndarray | tuple | list, name: str) -> np.ndarray:
    problem = ValueError(f"{name} must be 3 finite numbers or one of x, y, z; got {v!r}")
    if isinstance(v, str):
        if v not in _AXES:
            raise problem
        v = _AXES[v]
    out = np.asarray(v, dtype=float)
    if out.shape != (3,) or not np.all(np.isfinite(out)):
        raise problem
    return out


def skew(v: np.ndarray | tuple | list) -> np.ndarray:
    """The matrix S with S @ w == cross(v, w)."""
    x, y, z = _vector(v, "vector")
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def rotation_deg(axis: str | np.ndarray | tuple | list, angle_deg: float) -> np.ndarray:
    """3x3 rotation by `angle_deg` (right-handed) about `axis` ("x", "y", "z" or a vector)."""
    a = _vector(axis, "axis")
    norm = np.linalg.norm(a)
    if norm == 0:
        raise ValueError("rotation axis must not be zero")
    k = skew(a / norm)
    th = np.radians(angle_deg)
    return np.eye(3) + np.sin(th) * k + (1.0 - np.cos(th)) * (k @ k)


def wrench_transform(rotation: np.ndarray | None = None,
                     offset_m: np.ndarray | tuple | list = (0.0, 0.0, 0.0)) -> np.ndarray:
    """6x6 matrix taking a wrench at the sensor origin in sensor axes to the target frame.

    `offset_m` is the target point (e.g. the propeller centre) in sensor axes, in m.
    `rotation` maps sensor-axis coordinates to target-axis coordinates (identity if None).
    Forces are rotated; torques are moved to the target point (T - offset x F) and rotated.
    """
    r = np.eye(3) if rotation is None else np.asarray(rotation, dtype=float)
    if r.shape != (3, 3) or not np.allclose(r @ r.T, np.eye(3), atol=1e-9) \
            or not np.isclose(np.linalg.det(r), 1.0):
        raise ValueError("rotation must be a proper 3x3 rotation matrix (orthonormal, det +1)")
    m = np.zeros((6, 6))
    m[:3, :3] = r
    m[3:, 3:] = r
    m[3:, :3] = -r @ skew(offset_m)
    return m


def apply_transform(ft: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """Apply a 6x6 wrench transform to samples of shape (n, 6) (or one sample of shape (6,))."""
    ft = np.asarray(ft, dtype=float)
    if ft.shape[-1] != 6 or np.shape(matrix) != (6, 6):
        raise ValueError("need samples of 6 channels and a 6x6 matrix")
    return ft @ np.asarray(matrix, dtype=float).T


def thrust_along(ft: np.ndarray, axis: str | np.ndarray | tuple | list) -> np.ndarray:
    """Force component along `axis` (normalised), in sensor axes: one value per sample."""
    a = _vector(axis, "axis")
    norm = np.linalg.norm(a)
    if norm == 0:
        raise ValueError("thrust axis must not be zero")
    return np.asarray(ft, dtype=float)[..., :3] @ (a / norm)
