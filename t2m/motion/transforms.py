"""Whole-clip transforms on joint positions: mirroring (data augmentation), frame-rate change, heading."""
from __future__ import annotations

import numpy as np

from t2m.motion.features import forward_directions, validate_joints
from t2m.motion.skeleton import SMPL22, Skeleton, get_skeleton


def mirror_joints(joints: np.ndarray, skeleton: Skeleton | str = SMPL22) -> np.ndarray:
    """The clip reflected in the Y-Z plane: x negated and every left/right joint pair swapped (HumanML3D's M-clips)."""
    skeleton = get_skeleton(skeleton)
    positions = validate_joints(joints, skeleton)
    mirrored = positions[:, skeleton.mirror_permutation].copy()
    mirrored[..., 0] *= -1.0
    dtype = np.asarray(joints).dtype
    return mirrored.astype(dtype if np.issubdtype(dtype, np.floating) else np.float32)


def resample(joints: np.ndarray, src_fps: float, dst_fps: float) -> np.ndarray:
    """Linear interpolation in time (axis 0) from src_fps to dst_fps, starting at the first frame.

    Output frame k is at time k / dst_fps; frames continue while inside the clip, so the last input frame is kept
    whenever the clip's duration is a whole number of output frames (31 frames at 30 fps -> 21 frames at 20 fps).
    """
    array = np.asarray(joints)
    if array.ndim < 1 or len(array) < 1:
        raise ValueError(f"resample: need an array with at least one frame on axis 0, got shape {array.shape}")
    if not (np.isfinite(src_fps) and np.isfinite(dst_fps)) or src_fps <= 0 or dst_fps <= 0:
        raise ValueError(f"resample: frame rates must be positive, got src_fps={src_fps}, dst_fps={dst_fps}")
    num_in = len(array)
    duration_in_dst_frames = (num_in - 1) * dst_fps / src_fps
    num_out = int(np.floor(duration_in_dst_frames + 1e-6)) + 1
    position = np.minimum(np.arange(num_out) * (src_fps / dst_fps), num_in - 1)  # in input frames
    lower = np.floor(position).astype(int)
    upper = np.minimum(lower + 1, num_in - 1)
    weight = (position - lower).reshape((-1,) + (1,) * (array.ndim - 1))
    values = array.astype(np.float64)
    out = (1.0 - weight) * values[lower] + weight * values[upper]
    return out.astype(array.dtype if np.issubdtype(array.dtype, np.floating) else np.float64)


def facing_angle(joints: np.ndarray, skeleton: Skeleton | str = SMPL22) -> np.ndarray:
    """Heading per frame in radians, in (-pi, pi].

    0 means facing +Z. Positive angles are counter-clockwise seen from above (+Y looking down), i.e. a right-handed
    rotation about +Y, which turns +Z towards +X: the body's left (SMPL's left is +X when facing +Z). So an
    increasing angle means the person is turning left. Facing = up x ((r_hip - l_hip) + (r_shoulder - l_shoulder)),
    unsmoothed.
    """
    skeleton = get_skeleton(skeleton)
    forward = forward_directions(validate_joints(joints, skeleton), skeleton)
    return np.arctan2(forward[:, 0], forward[:, 2])
