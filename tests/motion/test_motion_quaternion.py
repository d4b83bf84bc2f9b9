"""Quaternion helpers against independent constructions (elementary rotation matrices, Rodrigues)."""
from __future__ import annotations

import numpy as np
import pytest

from t2m.motion.quaternion import (
    EULER_ORDERS,
    cont6d_to_matrix,
    euler_to_quat,
    matrix_to_quat,
    qbetween,
    qfrom_axis_angle,
    qinv,
    qmul,
    qnormalize,
    qrot,
    quat_to_cont6d,
    quat_to_euler,
    quat_to_matrix,
)

RNG = np.random.default_rng(11)


def elementary(axis: str, degrees: np.ndarray) -> np.ndarray:
    """Right-handed rotation matrices about one coordinate axis, written out by hand."""
    c, s = np.cos(np.deg2rad(degrees)), np.sin(np.deg2rad(degrees))
    one, zero = np.ones_like(c), np.zeros_like(c)
    rows = {
        "X": [[one, zero, zero], [zero, c, -s], [zero, s, c]],
        "Y": [[c, zero, s], [zero, one, zero], [-s, zero, c]],
        "Z": [[c, -s, zero], [s, c, zero], [zero, zero, one]],
    }[axis]
    return np.stack([np.stack(row, -1) for row in rows], -2)


def random_quats(n: int) -> np.ndarray:
    return qnormalize(RNG.normal(size=(n, 4)))


def same_rotation(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.minimum(np.abs(a - b).max(-1), np.abs(a + b).max(-1)).max())


@pytest.mark.parametrize("order", EULER_ORDERS)
def test_euler_matches_bvh_convention_and_round_trips(order):
    angles = RNG.uniform(-180, 180, size=(500, 3))
    angles[:, 1] = RNG.uniform(-89.5, 89.5, size=500)
    q = euler_to_quat(angles, order)
    first, second, third = (elementary(axis, angles[:, i]) for i, axis in enumerate(order))
    expected = first @ second @ third
    assert np.abs(quat_to_matrix(q) - expected).max() < 1e-12
    assert np.abs(quat_to_euler(q, order) - angles).max() < 1e-8
    radians = quat_to_euler(q, order, degrees=False)
    assert same_rotation(euler_to_quat(radians, order, degrees=False), q) < 1e-12


@pytest.mark.parametrize("order", EULER_ORDERS)
@pytest.mark.parametrize("middle", [90.0, -90.0])
def test_euler_gimbal_lock_still_gives_the_rotation(order, middle):
    angles = RNG.uniform(-180, 180, size=(100, 3))
    angles[:, 1] = middle
    q = euler_to_quat(angles, order)
    back = quat_to_euler(q, order)
    assert np.abs(quat_to_matrix(euler_to_quat(back, order)) - quat_to_matrix(q)).max() < 1e-6


def test_bad_euler_order():
    with pytest.raises(ValueError, match="Euler order must be one of"):
        euler_to_quat(np.zeros(3), "XXY")


def test_rotation_composition_and_inverse():
    a, b = random_quats(200), random_quats(200)
    v = RNG.normal(size=(200, 3))
    assert np.abs(qrot(qmul(a, b), v) - qrot(a, qrot(b, v))).max() < 1e-12
    assert np.abs(qrot(qinv(a), qrot(a, v)) - v).max() < 1e-12
    assert np.abs((quat_to_matrix(a) @ v[..., None])[..., 0] - qrot(a, v)).max() < 1e-12


def test_axis_angle_is_right_handed():
    q = qfrom_axis_angle(np.array([0.0, 1.0, 0.0]), np.pi / 2)
    assert np.allclose(qrot(q, np.array([0.0, 0.0, 1.0])), [1.0, 0.0, 0.0])
    axis = RNG.normal(size=(50, 3))
    angle = RNG.uniform(-3, 3, size=50)
    v = RNG.normal(size=(50, 3))
    k = axis / np.linalg.norm(axis, axis=-1, keepdims=True)
    rodrigues = (v * np.cos(angle)[:, None] + np.cross(k, v) * np.sin(angle)[:, None]
                 + k * (k * v).sum(-1, keepdims=True) * (1 - np.cos(angle))[:, None])
    assert np.abs(qrot(qfrom_axis_angle(axis, angle), v) - rodrigues).max() < 1e-12


def test_matrix_quaternion_round_trip_including_half_turns():
    q = random_quats(500)
    half_turns = qfrom_axis_angle(RNG.normal(size=(50, 3)), np.full(50, np.pi))
    for quats in (q, half_turns, np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]])):
        back = matrix_to_quat(quat_to_matrix(quats))
        assert same_rotation(back, quats) < 1e-9
        assert np.all(back[..., 0] >= 0)


def test_cont6d_round_trip_and_gram_schmidt():
    q = random_quats(100)
    d6 = quat_to_cont6d(q)
    assert d6.shape == (100, 6)
    assert np.abs(cont6d_to_matrix(d6) - quat_to_matrix(q)).max() < 1e-12
    noisy = cont6d_to_matrix(d6 * 3.0 + 0.01 * RNG.normal(size=d6.shape))
    assert np.abs(noisy @ np.swapaxes(noisy, -1, -2) - np.eye(3)).max() < 1e-12
    assert np.allclose(np.linalg.det(noisy), 1.0)


def test_qbetween_maps_directions_including_parallel_and_opposite():
    a = RNG.normal(size=(300, 3))
    b = RNG.normal(size=(300, 3))
    b[:100] = -a[:100] * 2.5  # opposite
    b[100:150] = a[100:150] * 0.3  # parallel
    a[:3] = [[1, 0, 0], [0, -1, 0], [0, 0, 1]]  # opposite along axes (helper-axis corner cases)
    b[:3] = -a[:3]
    q = qbetween(a, b)
    unit = lambda x: x / np.linalg.norm(x, axis=-1, keepdims=True)  # noqa: E731
    assert np.all(np.isfinite(q))
    assert np.abs(np.linalg.norm(q, axis=-1) - 1).max() < 1e-12
    assert np.abs(qrot(q, unit(a)) - unit(b)).max() < 1e-9
    assert np.allclose(q[100:150], [1, 0, 0, 0])
