"""Axis mapping for mounted F/T sensors: rotations, moving the torque reference point."""

from __future__ import annotations

import numpy as np
import pytest

from rigtool.devices.axes import (
    apply_transform,
    rotation_deg,
    skew,
    thrust_along,
    wrench_transform,
)


def test_skew_is_the_cross_product():
    v, w = np.array([1.0, -2.0, 0.5]), np.array([0.3, 4.0, -1.0])
    assert skew(v) @ w == pytest.approx(np.cross(v, w))


def test_rotation_about_z_takes_x_to_y():
    r = rotation_deg("z", 90)
    assert r @ [1, 0, 0] == pytest.approx([0, 1, 0], abs=1e-12)
    assert rotation_deg([0, 0, 2], 90) == pytest.approx(r)  # axis need not be unit length


def test_pure_rotation_maps_force_and_torque_alike():
    m = wrench_transform(rotation_deg("z", 90))
    out = apply_transform(np.array([[10.0, 0, 0, 1.0, 0, 0]]), m)
    assert out[0] == pytest.approx([0, 10.0, 0, 0, 1.0, 0], abs=1e-12)


def test_offset_moves_the_torque_reference_point():
    # 10 N along x acting on a line through (0, 0, 0.1) m in sensor axes: the sensor sees
    # Ty = +1 N m about its origin (r x F = (0,0,0.1) x (10,0,0)); about that point, none.
    ft_sensor = np.array([10.0, 0, 0, 0, 1.0, 0])
    out = apply_transform(ft_sensor, wrench_transform(offset_m=(0, 0, 0.1)))
    assert out == pytest.approx([10.0, 0, 0, 0, 0, 0], abs=1e-12)


def test_transform_round_trip_and_nan_channels():
    r = rotation_deg([1, 1, 0], 30)
    m = wrench_transform(r, (0.05, -0.02, 0.1))
    back = wrench_transform(r.T, -r @ np.array([0.05, -0.02, 0.1]))
    ft = np.random.default_rng(0).normal(size=(20, 6))
    assert apply_transform(apply_transform(ft, m), back) == pytest.approx(ft)
    one_axis = np.array([[2.0, np.nan, np.nan, np.nan, np.nan, np.nan]])
    assert np.all(np.isnan(apply_transform(one_axis, m)))  # a single-axis gauge cannot be rotated


def test_thrust_along_a_tilted_axis():
    ft = np.array([[3.0, 4.0, 0, 0, 0, 0], [1.0, 1.0, 1.0, 9, 9, 9]])
    assert thrust_along(ft, [3, 4, 0]) == pytest.approx([5.0, 7 / 5])
    assert thrust_along(ft, "x") == pytest.approx([3.0, 1.0])


@pytest.mark.parametrize("call, fragment", [
    (lambda: wrench_transform(np.diag([1.0, 1.0, -1.0])), "proper 3x3 rotation"),
    (lambda: wrench_transform(np.ones((3, 3))), "proper 3x3 rotation"),
    (lambda: rotation_deg("w", 10), "one of x, y, z"),
    (lambda: rotation_deg([0, 0, 0], 10), "must not be zero"),
    (lambda: thrust_along(np.zeros((1, 6)), [0, 0, 0]), "must not be zero"),
    (lambda: apply_transform(np.zeros((2, 3)), np.eye(6)), "6 channels"),
])
def test_bad_input(call, fragment):
    with pytest.raises(ValueError, match=fragment):
        call()
