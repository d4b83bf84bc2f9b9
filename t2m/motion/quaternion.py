"""Quaternion and rotation helpers in numpy, (w, x, y, z) order, vectorised over any leading dimensions.

Why our own: the motion core must run without torch or scipy, and HumanML3D's features are defined in terms of
exactly these operations (shortest-arc rotations, 6D = the first two matrix columns), so their conventions are
spelled out here once.
"""
from __future__ import annotations

import numpy as np

_EPS = 1e-12
EULER_ORDERS = ("XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX")
_AXIS_INDEX = {"X": 0, "Y": 1, "Z": 2}


def _as_float(array: np.ndarray) -> np.ndarray:
    array = np.asarray(array)
    return array if np.issubdtype(array.dtype, np.floating) else array.astype(np.float64)


def qnormalize(q: np.ndarray) -> np.ndarray:
    """Unit quaternions (a zero quaternion stays zero rather than becoming NaN)."""
    q = _as_float(q)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    return q / np.maximum(norm, _EPS)


def qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b (apply b first, then a). Broadcasts."""
    a, b = _as_float(a), _as_float(b)
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def qinv(q: np.ndarray) -> np.ndarray:
    """Inverse of a unit quaternion (its conjugate)."""
    q = _as_float(q)
    return q * np.array([1.0, -1.0, -1.0, -1.0], dtype=q.dtype)


def qrot(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors v [..., 3] by unit quaternions q [..., 4]. Broadcasts."""
    q, v = _as_float(q), _as_float(v)
    w = q[..., :1]
    u = q[..., 1:]
    uv = np.cross(u, v)
    uuv = np.cross(u, uv)
    return v + 2.0 * (w * uv + uuv)


def qbetween(v0: np.ndarray, v1: np.ndarray) -> np.ndarray:
    """Shortest-arc rotation taking direction v0 to direction v1.

    Same formula as HumanML3D (w = |v0||v1| + v0.v1, xyz = v0 x v1, normalised), so features computed with it match
    theirs; unlike theirs it stays defined for opposite vectors (a half turn about an axis perpendicular to v0).
    """
    v0, v1 = np.broadcast_arrays(_as_float(v0), _as_float(v1))
    axis = np.cross(v0, v1)
    w = np.sqrt((v0**2).sum(-1) * (v1**2).sum(-1)) + (v0 * v1).sum(-1)
    q = np.concatenate([w[..., None], axis], axis=-1)
    norm = np.linalg.norm(q, axis=-1)
    scale = np.sqrt((v0**2).sum(-1) * (v1**2).sum(-1))
    opposite = norm <= 1e-7 * np.maximum(scale, _EPS)
    if np.any(opposite):
        a = v0[opposite]
        # any axis perpendicular to v0: cross with the coordinate axis least aligned with it
        helper = np.eye(3)[np.argmin(np.abs(a), axis=-1)]
        perpendicular = np.cross(a, helper)
        q = q.copy()
        q[opposite] = np.concatenate([np.zeros((len(a), 1)), perpendicular], axis=-1)
    return qnormalize(q)


def qfrom_axis_angle(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotation of `angle` radians about `axis` (normalised here). Broadcasts."""
    axis = _as_float(axis)
    angle = _as_float(angle)
    axis = axis / np.maximum(np.linalg.norm(axis, axis=-1, keepdims=True), _EPS)
    half = 0.5 * angle[..., None]
    return np.concatenate([np.cos(half), np.sin(half) * axis], axis=-1)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices [..., 3, 3] of (normalised) quaternions; R @ v == qrot(q, v)."""
    w, x, y, z = np.moveaxis(qnormalize(q), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """Quaternions (w >= 0) of rotation matrices [..., 3, 3], choosing the numerically best branch per matrix."""
    m = _as_float(m)
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    # 4*|component|^2 for w, x, y, z; the largest one gives a well-conditioned division
    squares = np.stack(
        [1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], axis=-1
    )
    best = np.argmax(squares, axis=-1)
    root = np.sqrt(np.maximum(np.take_along_axis(squares, best[..., None], -1)[..., 0], _EPS))  # = 4|c| / 2 = 2|c|
    # the off-diagonal differences are 4w*(x, y, z), the sums 4xy, 4xz, 4yz
    wx4, wy4, wz4 = m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]
    xy4, xz4, yz4 = m[..., 1, 0] + m[..., 0, 1], m[..., 0, 2] + m[..., 2, 0], m[..., 2, 1] + m[..., 1, 2]
    rr = root * root
    candidates = np.stack(
        [
            np.stack([rr, wx4, wy4, wz4], -1),
            np.stack([wx4, rr, xy4, xz4], -1),
            np.stack([wy4, xy4, rr, yz4], -1),
            np.stack([wz4, xz4, yz4, rr], -1),
        ],
        axis=-2,
    )
    q = np.take_along_axis(candidates, best[..., None, None], axis=-2)[..., 0, :] / (2.0 * root[..., None])
    q = qnormalize(q)
    return np.where(q[..., :1] < 0, -q, q)


def quat_to_cont6d(q: np.ndarray) -> np.ndarray:
    """6D continuous representation: the first two columns of the rotation matrix, concatenated (HumanML3D's)."""
    m = quat_to_matrix(q)
    return np.concatenate([m[..., :, 0], m[..., :, 1]], axis=-1)


def cont6d_to_matrix(d6: np.ndarray) -> np.ndarray:
    """Rotation matrices from 6D vectors by Gram-Schmidt (columns x, y, z)."""
    d6 = _as_float(d6)
    x = d6[..., 0:3]
    x = x / np.maximum(np.linalg.norm(x, axis=-1, keepdims=True), _EPS)
    z = np.cross(x, d6[..., 3:6])
    z = z / np.maximum(np.linalg.norm(z, axis=-1, keepdims=True), _EPS)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=-1)


def _check_order(order: str) -> str:
    order = order.upper()
    if order not in EULER_ORDERS:
        raise ValueError(f"Euler order must be one of {', '.join(EULER_ORDERS)}, got {order!r}")
    return order


def euler_to_quat(angles: np.ndarray, order: str = "ZXY", degrees: bool = True) -> np.ndarray:
    """Quaternions of Euler angles [..., 3] given in the listed order (BVH convention).

    angles[..., i] is the rotation about axis order[i]; the rotations are intrinsic and applied in the listed
    order, so the result is R = R_order[0] @ R_order[1] @ R_order[2] (what BVH readers do channel by channel).
    """
    order = _check_order(order)
    angles = _as_float(angles)
    if degrees:
        angles = np.deg2rad(angles)
    q = np.zeros(angles.shape[:-1] + (4,), dtype=angles.dtype)
    q[..., 0] = 1.0
    for i, axis_name in enumerate(order):
        axis = np.zeros(3)
        axis[_AXIS_INDEX[axis_name]] = 1.0
        q = qmul(q, qfrom_axis_angle(axis, angles[..., i]))
    return q


def quat_to_euler(q: np.ndarray, order: str = "ZXY", degrees: bool = True) -> np.ndarray:
    """Inverse of `euler_to_quat`: angles [..., 3] about order[0], order[1], order[2] with R = R0 @ R1 @ R2.

    The middle angle lies in [-90, 90] degrees; at gimbal lock the third angle is set to 0.
    """
    order = _check_order(order)
    m = quat_to_matrix(q)
    i, j, k = (_AXIS_INDEX[a] for a in order)
    # parity: +1 for cyclic orders (XYZ, YZX, ZXY), -1 otherwise
    sign = 1.0 if (j - i) % 3 == 1 else -1.0
    # For R = Ri(a) Rj(b) Rk(c): R[i, k] = sign * sin(b)
    sin_b = np.clip(sign * m[..., i, k], -1.0, 1.0)
    b = np.arcsin(sin_b)
    cos_b = np.sqrt(np.maximum(1.0 - sin_b**2, 0.0))
    locked = cos_b < 1e-6
    a = np.arctan2(-sign * m[..., j, k], m[..., k, k])
    c = np.arctan2(-sign * m[..., i, j], m[..., i, i])
    if np.any(locked):
        # only a +/- c is determined; put it all in a (c = 0): then R[j, j] = cos a and R[k, j] = sign * sin a
        a_locked = np.arctan2(sign * m[..., k, j], m[..., j, j])
        a = np.where(locked, a_locked, a)
        c = np.where(locked, 0.0, c)
    angles = np.stack([a, b, c], axis=-1)
    return np.rad2deg(angles) if degrees else angles
