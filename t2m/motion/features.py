"""HumanML3D motion features <-> joint positions, and HumanML3D's joint normalisation.

Layout of one feature row (J joints, D = 12 * J - 1; 263 for SMPL-22, 251 for KIT-21):
    0            root angular velocity about Y (half-angle convention: the root quaternion is (cos a, 0, sin a, 0));
                 the root quaternion turns the facing direction onto +Z, so a positive value is a clockwise turn
                 seen from above (towards -X, the body's right), the opposite sign of `transforms.facing_angle`
    1:3          root linear velocity on X-Z, in the facing frame of the next frame
    3            root height
    4:4+3(J-1)               ric: joints relative to the root's x/z, rotated into the facing frame
    next 6(J-1)              6D local rotations (HumanML3D's per-chain IK; not used to recover positions)
    next 3J                  local velocities: displacement to the next frame, in this frame's facing frame
    last 4                   foot contacts (l_heel, l_toe, r_heel, r_toe)

Frame alignment (checked on the HumanML3D sample 012314): a clip of T joint frames gives T-1 feature rows; row t
holds frame t's pose and the step from frame t to t+1. HumanML3D's new_joints/<id>.npy are the joints *recovered*
from the T-1 rows, so they have as many frames as the feature file, and frame t of them is exactly frame t of the
normalised original clip (frame 0's root rotation is the identity). The original's last frame is not stored, but
the last feature row's local velocities give it back: new_joints plus that frame reproduce every one of the 263
channels of all rows to < 1e-5. From new_joints alone one gets one row fewer, and because the facing direction is
smoothed over time (Gaussian, sigma 20 frames, radius 80, edges repeated), rows within 80 frames of the end shift
slightly (up to ~7e-3 on the sample); the rows before that match to ~1e-7.

The facing frame is HumanML3D's: forward = up x across, with across from the hip and shoulder lines (see
`humanml3d_ik` for the exact signs), smoothed over time, then the root rotation turns it onto +Z.
"""
from __future__ import annotations

from itertools import pairwise

import numpy as np

from t2m.motion.quaternion import qbetween, qinv, qmul, qrot, quat_to_cont6d
from t2m.motion.skeleton import SMPL22, Skeleton, get_skeleton

_UP = np.array([0.0, 1.0, 0.0])
_FORWARD = np.array([0.0, 0.0, 1.0])
FORWARD_SMOOTHING_SIGMA = 20.0  # frames; HumanML3D smooths the forward direction before taking the root rotation


def feature_dim(skeleton: Skeleton | str = SMPL22) -> int:
    """Channels per frame: 4 root + 3(J-1) ric + 6(J-1) rotations + 3J velocities + 4 contacts = 12J - 1."""
    return 12 * get_skeleton(skeleton).num_joints - 1


# ---------------------------------------------------------------- validation


def _check_finite(array: np.ndarray, what: str) -> None:
    if not np.all(np.isfinite(array)):
        bad = np.argwhere(~np.isfinite(array))[0]
        raise ValueError(f"{what} contain NaN or inf (first at index {tuple(int(i) for i in bad)})")


def validate_features(features: np.ndarray, skeleton: Skeleton | str = SMPL22, min_frames: int = 1) -> np.ndarray:
    """Check a feature array is [T, D] for this skeleton, finite, T >= min_frames; return it as float64."""
    skeleton = get_skeleton(skeleton)
    dim = feature_dim(skeleton)
    array = np.asarray(features)
    if array.ndim != 2 or array.shape[1] != dim or array.shape[0] < min_frames:
        raise ValueError(f"features must have shape [T, {dim}] with T >= {min_frames}, got {array.shape}")
    if not np.issubdtype(array.dtype, np.number):
        raise ValueError(f"features must be numeric, got dtype {array.dtype}")
    array = array.astype(np.float64)
    _check_finite(array, "features")
    return array


def validate_joints(joints: np.ndarray, skeleton: Skeleton | str = SMPL22, min_frames: int = 1) -> np.ndarray:
    """Check a joint array is [T, J, 3] for this skeleton, finite, T >= min_frames; return it as float64."""
    skeleton = get_skeleton(skeleton)
    array = np.asarray(joints)
    if array.ndim != 3 or array.shape[1:] != (skeleton.num_joints, 3) or array.shape[0] < min_frames:
        raise ValueError(
            f"joints must have shape [T, {skeleton.num_joints}, 3] with T >= {min_frames}, got {array.shape}"
        )
    if not np.issubdtype(array.dtype, np.number):
        raise ValueError(f"joints must be numeric, got dtype {array.dtype}")
    array = array.astype(np.float64)
    _check_finite(array, "joints")
    return array


# ---------------------------------------------------------------- features -> joints


def _heading_quats(angles: np.ndarray) -> np.ndarray:
    """Root quaternions (cos a, 0, sin a, 0) of the heading angles a."""
    quats = np.zeros((len(angles), 4))
    quats[:, 0] = np.cos(angles)
    quats[:, 2] = np.sin(angles)
    return quats


def _running_sum(values: np.ndarray, carry: np.ndarray | None) -> np.ndarray:
    """Cumulative sums along axis 0 continuing from `carry` (None: from nothing), added in the order one cumsum over
    the whole sequence adds them, so that sums made in pieces equal the sums made at once bit for bit."""
    if carry is None:
        return np.cumsum(values, axis=0)
    return np.cumsum(np.concatenate([carry[None], values]), axis=0)[1:]


class JointRecovery:
    """Feature rows -> joint positions, in pieces. A frame depends on its own row and the rows before it (the heading
    and the root position are running sums of the rows' velocities), never on later rows, so joints can be recovered
    while a motion is still being decoded (streaming); every piece equals the same frames of `features_to_joints`
    over the whole motion, bit for bit."""

    def __init__(self, skeleton: Skeleton | str = SMPL22) -> None:
        self.skeleton = get_skeleton(skeleton)
        self.heading: np.ndarray | None = None      # root quaternion of the last frame recovered
        self._angle: np.ndarray | None = None       # its heading angle
        self._root: np.ndarray | None = None        # its root position [3] (before the height is set)
        self._last_row: np.ndarray | None = None    # its feature row: its velocities move the root to the next frame

    def push(self, features: np.ndarray) -> np.ndarray:
        """Joint positions [T, J, 3] (float64) of the next T feature rows [T, D]."""
        data = validate_features(features, self.skeleton)
        num_frames, num_joints = len(data), self.skeleton.num_joints
        # row t-1 turns the heading and moves the root to frame t; the very first frame has no row before it
        before = data[:-1] if self._last_row is None else np.concatenate([self._last_row[None], data[:-1]])
        angles = (np.concatenate([[0.0], np.cumsum(before[:, 0])]) if self._angle is None
                  else _running_sum(before[:, 0], self._angle))
        root_quat = _heading_quats(angles)
        step = np.zeros((num_frames, 3))
        step[num_frames - len(before):, [0, 2]] = before[:, 1:3]
        root = _running_sum(qrot(qinv(root_quat), step), self._root)
        self._angle, self._root, self._last_row = np.asarray(angles[-1]), root[-1].copy(), data[-1].copy()
        self.heading = root_quat[-1]
        root[:, 1] = data[:, 3]
        ric = data[:, 4 : 4 + 3 * (num_joints - 1)].reshape(num_frames, num_joints - 1, 3)
        others = qrot(qinv(root_quat)[:, None, :], ric)
        others[..., 0] += root[:, None, 0]
        others[..., 2] += root[:, None, 2]
        return np.concatenate([root[:, None, :], others], axis=1)


def features_to_joints(features: np.ndarray, skeleton: Skeleton | str = SMPL22,
                       with_final_frame: bool = False) -> np.ndarray:
    """Joint positions [T, J, 3] (float32) from features [T, D]; uses the root and ric channels only.

    with_final_frame=True appends the frame the last row's local velocities lead to ([T+1, J, 3]): the clip the
    features were extracted from, which HumanML3D's own recovery drops.
    """
    recovery = JointRecovery(skeleton)
    joints = recovery.push(features)
    if with_final_frame and recovery.heading is not None:
        num_joints = recovery.skeleton.num_joints
        first = 4 + 9 * (num_joints - 1)
        velocity = np.asarray(features, dtype=np.float64)[-1, first : first + 3 * num_joints]
        step = qrot(qinv(recovery.heading), velocity.reshape(num_joints, 3))
        joints = np.concatenate([joints, (joints[-1] + step)[None]], axis=0)
    return joints.astype(np.float32)


# ---------------------------------------------------------------- joints -> features


def gaussian_smooth(values: np.ndarray, sigma: float, axis: int = 0) -> np.ndarray:
    """Gaussian filter along `axis` with edge values repeated (as scipy.ndimage.gaussian_filter1d, mode='nearest',
    truncate=4), written in numpy so the motion core needs no scipy."""
    radius = int(4.0 * sigma + 0.5)
    taps = np.arange(-radius, radius + 1)
    kernel = np.exp(-0.5 * (taps / sigma) ** 2)
    kernel /= kernel.sum()
    moved = np.moveaxis(np.asarray(values, dtype=np.float64), axis, 0)
    padded = np.concatenate([np.repeat(moved[:1], radius, 0), moved, np.repeat(moved[-1:], radius, 0)], axis=0)
    out = np.zeros_like(moved)
    for offset, weight in enumerate(kernel):
        out += weight * padded[offset : offset + len(moved)]
    return np.moveaxis(out, 0, axis)


def forward_directions(joints: np.ndarray, skeleton: Skeleton, smooth_sigma: float | None = None) -> np.ndarray:
    """Unit horizontal facing direction per frame [T, 3] from the hip and shoulder lines (optionally smoothed)."""
    r_hip, l_hip, r_shoulder, l_shoulder = skeleton.face_joints
    across = (joints[:, r_hip] - joints[:, l_hip]) + (joints[:, r_shoulder] - joints[:, l_shoulder])
    return _forward_of_across(across, smooth_sigma)


def _forward_of_across(across: np.ndarray, smooth_sigma: float | None) -> np.ndarray:
    across = across / np.maximum(np.linalg.norm(across, axis=-1, keepdims=True), 1e-12)
    forward = np.cross(_UP, across)
    if smooth_sigma:
        forward = gaussian_smooth(forward, smooth_sigma, axis=0)
    norm = np.linalg.norm(forward, axis=-1, keepdims=True)
    if np.any(norm < 1e-9):
        raise ValueError("joints: the hip and shoulder lines are vertical or degenerate; cannot find the facing")
    return forward / norm


def humanml3d_ik(joints: np.ndarray, skeleton: Skeleton, smooth_sigma: float | None = None,
                 with_facing: bool = True) -> np.ndarray:
    """HumanML3D's inverse kinematics: local quaternions [T, J, 4] from positions.

    The root rotation turns the facing direction onto +Z. Each chain restarts from the root rotation; joint j's
    local rotation is inv(R_parent_accumulated) * shortest_arc(rest direction of j, observed bone direction of j).
    Twist about a bone is not observable from positions and is left out (the shortest arc has none).

    Two HumanML3D details are kept on purpose, because released features and models depend on them (both verified
    on the sample 012314): the IK's facing uses (l_hip - r_hip) + (r_shoulder - l_shoulder), i.e. the hip line
    enters with the opposite sign of `normalize_joints`'s facing, and frame 0's root rotation is the identity
    (the clip is normalised to face +Z at frame 0). with_facing=False keeps every root rotation at the identity,
    enough when only bone directions matter (retargeting) and defined even where the facing is not.
    """
    num_frames = len(joints)
    root_quat = np.zeros((num_frames, 4))
    root_quat[:, 0] = 1.0
    if with_facing:
        r_hip, l_hip, r_shoulder, l_shoulder = skeleton.face_joints
        across = (joints[:, l_hip] - joints[:, r_hip]) + (joints[:, r_shoulder] - joints[:, l_shoulder])
        root_quat[1:] = qbetween(_forward_of_across(across, smooth_sigma), _FORWARD)[1:]
    directions = skeleton.rest_directions
    quats = np.zeros((num_frames, skeleton.num_joints, 4))
    quats[..., 0] = 1.0
    quats[:, 0] = root_quat
    for chain in skeleton.kinematic_chain:
        accumulated = root_quat
        for parent, child in pairwise(chain):
            bone = joints[:, child] - joints[:, parent]
            world = qbetween(np.broadcast_to(directions[child], bone.shape), bone)
            local = qmul(qinv(accumulated), world)
            quats[:, child] = local
            accumulated = qmul(accumulated, local)
    return quats


def forward_kinematics(local_quats: np.ndarray, root_positions: np.ndarray, skeleton: Skeleton,
                       offsets: np.ndarray | None = None) -> np.ndarray:
    """Positions [T, J, 3] from HumanML3D-style local quaternions (each chain starting from the root rotation)."""
    offsets = skeleton.offsets if offsets is None else np.asarray(offsets, dtype=np.float64)
    joints = np.zeros(local_quats.shape[:-1] + (3,))
    joints[:, 0] = root_positions
    for chain in skeleton.kinematic_chain:
        accumulated = local_quats[:, 0]
        for parent, child in pairwise(chain):
            accumulated = qmul(accumulated, local_quats[:, child])
            offset = np.broadcast_to(offsets[child], joints[:, child].shape)
            joints[:, child] = qrot(accumulated, offset) + joints[:, parent]
    return joints


def joints_to_features(joints: np.ndarray, skeleton: Skeleton | str = SMPL22,
                       feet_threshold: float | None = None) -> np.ndarray:
    """HumanML3D features [T-1, D] (float32) of joints [T, J, 3] that are already normalised (`normalize_joints`).

    feet_threshold: squared per-frame displacement under which a heel/toe counts as in contact; defaults to
    HumanML3D's value for the skeleton (0.002 m^2 for SMPL-22; 0.05 for KIT-21 in millimetres).
    """
    skeleton = get_skeleton(skeleton)
    positions = validate_joints(joints, skeleton, min_frames=2)
    threshold = skeleton.feet_threshold if feet_threshold is None else float(feet_threshold)
    num_frames = positions.shape[0]

    # foot contacts: squared displacement to the next frame under the threshold
    feet = list(skeleton.foot_joints)
    step = positions[1:, feet] - positions[:-1, feet]
    contacts = ((step**2).sum(-1) < threshold).astype(np.float64)

    local_quats = humanml3d_ik(positions, skeleton, smooth_sigma=FORWARD_SMOOTHING_SIGMA)
    rotations_6d = quat_to_cont6d(local_quats[:, 1:]).reshape(num_frames, -1)
    root_quat = local_quats[:, 0]

    # root: heading change (half angle, from the y component), velocity in the next frame's facing frame, height
    root_velocity = qrot(root_quat[1:], positions[1:, 0] - positions[:-1, 0])
    heading_change = qmul(root_quat[1:], qinv(root_quat[:-1]))
    angular_velocity = np.arcsin(np.clip(heading_change[:, 2], -1.0, 1.0))
    root_data = np.concatenate(
        [angular_velocity[:, None], root_velocity[:, [0, 2]], positions[:-1, 0, 1:2]], axis=-1
    )

    # ric: relative to the root's x/z, in each frame's facing frame
    relative = positions.copy()
    relative[..., 0] -= positions[:, 0:1, 0]
    relative[..., 2] -= positions[:, 0:1, 2]
    ric = qrot(root_quat[:, None, :], relative)[:, 1:].reshape(num_frames, -1)

    local_velocity = qrot(root_quat[:-1, None, :], positions[1:] - positions[:-1]).reshape(num_frames - 1, -1)

    features = np.concatenate(
        [root_data, ric[:-1], rotations_6d[:-1], local_velocity, contacts], axis=-1
    )
    return features.astype(np.float32)


# ---------------------------------------------------------------- normalisation


def retarget_to_reference(joints: np.ndarray, skeleton: Skeleton) -> np.ndarray:
    """Same motion on the skeleton's reference bone lengths: IK then FK keeping every bone direction.

    The root trajectory is scaled by the ratio of reference to observed leg length (knee-ankle + hip-knee of the
    first chain), so a short person's stride becomes the reference person's stride (HumanML3D's uniform_skeleton).
    """
    leg = skeleton.kinematic_chain[0][2:4]  # knee and ankle of the first leg chain
    observed = sum(np.linalg.norm(joints[0, j] - joints[0, skeleton.parents[j]]) for j in leg)
    reference = sum(skeleton.bone_lengths[j] for j in leg)
    if observed <= 0:
        raise ValueError("joints: the first frame has a zero-length leg; cannot scale to the reference skeleton")
    local_quats = humanml3d_ik(joints, skeleton, with_facing=False)
    return forward_kinematics(local_quats, joints[:, 0] * (reference / observed), skeleton)


def normalize_joints(joints: np.ndarray, skeleton: Skeleton | str = SMPL22) -> np.ndarray:
    """HumanML3D's processing of raw joints [T, J, 3] (metres, Y up) before feature extraction.

    Reference bone lengths; lowest joint of the whole clip on y = 0; first root at x = z = 0; rotated about Y so the
    first frame faces +Z (unsmoothed facing of frame 0). Returns float32.
    """
    skeleton = get_skeleton(skeleton)
    positions = retarget_to_reference(validate_joints(joints, skeleton), skeleton)
    positions[..., 1] -= positions[..., 1].min()
    positions -= positions[0, 0] * np.array([1.0, 0.0, 1.0])
    first_forward = forward_directions(positions[:1], skeleton)
    turn = qbetween(first_forward, _FORWARD)[0]
    return qrot(turn, positions).astype(np.float32)
