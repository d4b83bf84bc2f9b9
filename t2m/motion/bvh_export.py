"""Joint positions -> a BVH file that animation tools (Blender, MotionBuilder, Unity/Unreal importers) read.

Choices, deliberately fixed so every file looks the same:
- joint names are the conventional Mixamo-style ones (Hips, LeftUpLeg, ..., RightHand), so retargeting presets
  recognise them; the hierarchy is the SMPL-22 tree with an End Site on each leaf (Head, hands, toes);
- units are CENTIMETRES (the BVH convention; in Blender import with scale 0.01 to get metres), Y up, the body
  facing +Z in the rest pose; Frame Time = 1 / fps (0.05 s at 20 fps);
- the root (Hips) has 6 channels `Xposition Yposition Zposition Yrotation Xrotation Zrotation` and OFFSET 0 0 0,
  so its position channels are the absolute pelvis position whether a reader adds them to the offset or replaces
  it. Heading is the first (outermost) angle, so a character turning round never hits gimbal lock (that needs
  the pelvis pitched 90 degrees, i.e. lying flat);
- every other joint has 3 channels `Zrotation Yrotation Xrotation` (R = Rz @ Ry @ Rx, degrees): the limbs and the
  spine lie along Y in the rest pose, so the middle angle is the twist about the bone, the one that rarely
  reaches 90 degrees;
- each Euler channel is unwrapped over time (adding 360 never changes a rotation), so curves have no 360-degree
  jumps for the tool to interpolate across;
- values are rounded to 1e-6 and written with 7 significant digits (at worst 1e-3 cm / 1e-3 degrees for values
  in the thousands; sub-millimetre either way).
The rotations come from `motion.ik.joints_to_rotations`; the offsets are the motion's own bone lengths, so reading
the file back with forward kinematics gives the joints back (error < 0.01 mm on HumanML3D data; on generated
motion, whose bone lengths wobble, about the wobble).
"""
from __future__ import annotations

import numpy as np

from t2m.motion.bvh import BvhMotion, write_bvh
from t2m.motion.constants import FPS
from t2m.motion.ik import joints_to_rotations
from t2m.motion.quaternion import quat_to_euler
from t2m.motion.skeleton import SMPL22, Skeleton, get_skeleton

__all__ = [
    "BVH_NAMES",
    "CM_PER_METRE",
    "JOINT_CHANNELS",
    "ROOT_CHANNELS",
    "bvh_joint_names",
    "joints_to_bvh",
    "joints_to_bvh_motion",
]

CM_PER_METRE = 100.0
ROOT_CHANNELS = ("Xposition", "Yposition", "Zposition", "Yrotation", "Xrotation", "Zrotation")
JOINT_CHANNELS = ("Zrotation", "Yrotation", "Xrotation")
_PRECISION = 7

# SMPL-22 joint -> conventional (Mixamo-style) BVH joint name.
BVH_NAMES = {
    "pelvis": "Hips", "left_hip": "LeftUpLeg", "right_hip": "RightUpLeg", "spine1": "Spine",
    "left_knee": "LeftLeg", "right_knee": "RightLeg", "spine2": "Spine1", "left_ankle": "LeftFoot",
    "right_ankle": "RightFoot", "spine3": "Spine2", "left_foot": "LeftToe", "right_foot": "RightToe",
    "neck": "Neck", "left_collar": "LeftShoulder", "right_collar": "RightShoulder", "head": "Head",
    "left_shoulder": "LeftArm", "right_shoulder": "RightArm", "left_elbow": "LeftForeArm",
    "right_elbow": "RightForeArm", "left_wrist": "LeftHand", "right_wrist": "RightHand",
}
# Length (metres) of each leaf's End Site, which continues the leaf's bone: top of the head, hand and toe tips.
# (Along the bone, not along rest +Y: HumanML3D's rest neck->head bone points forward, and the head inherits the
# neck's rotation, so only the bone's own direction is guaranteed to point out of the top of the head.)
_END_SITE_LENGTHS = {"head": 0.10, "left_wrist": 0.08, "right_wrist": 0.08, "left_foot": 0.05, "right_foot": 0.05}


def bvh_joint_names(skeleton: Skeleton | str = SMPL22) -> list[str]:
    """The BVH name of each joint of `skeleton`, in the skeleton's joint order (unknown joints keep their name)."""
    skeleton = get_skeleton(skeleton)
    return [BVH_NAMES.get(name, name) for name in skeleton.joint_names]


def _end_site(skeleton: Skeleton, joint: int, offsets: np.ndarray) -> np.ndarray:
    length = float(np.linalg.norm(offsets[joint]))
    direction = offsets[joint] / length if length > 1e-9 else np.array([0.0, 1.0, 0.0])
    # other skeletons: continue the leaf's bone by half its length
    return direction * _END_SITE_LENGTHS.get(skeleton.joint_names[joint], 0.5 * length)


def joints_to_bvh_motion(joints: np.ndarray, skeleton: Skeleton | str = SMPL22, fps: float = FPS) -> BvhMotion:
    """The BvhMotion (centimetres, degrees) whose forward kinematics reproduces `joints` [T, J, 3] (metres)."""
    skeleton = get_skeleton(skeleton)
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be a positive number, got {fps}")
    solved = joints_to_rotations(joints, skeleton)
    frames, count = solved.local_quats.shape[:2]
    columns: list[np.ndarray] = []
    channels: list[tuple[str, ...]] = []
    for joint, parent in enumerate(skeleton.parents):
        if parent < 0:
            order = "".join(c[0] for c in ROOT_CHANNELS[3:])
            columns.append(solved.root_positions * CM_PER_METRE)
            channels.append(ROOT_CHANNELS)
        else:
            order = "".join(c[0] for c in JOINT_CHANNELS)
            channels.append(JOINT_CHANNELS)
        angles = quat_to_euler(solved.local_quats[:, joint], order=order, degrees=True)
        columns.append(np.unwrap(angles, period=360.0, axis=0))
    offsets = solved.offsets * CM_PER_METRE
    offsets[[j for j, p in enumerate(skeleton.parents) if p < 0]] = 0.0  # root: the position channels say it all
    has_child = {p for p in skeleton.parents if p >= 0}
    leaves = [j for j in range(count) if j not in has_child]
    return BvhMotion(
        joint_names=bvh_joint_names(skeleton),
        parents=np.array(skeleton.parents),
        offsets=offsets,
        channels=channels,
        frame_time=1.0 / fps,
        # rounding to 1e-6 (cm, degrees) drops float noise like 2e-12 that would only bloat the text
        motion=np.round(np.concatenate(columns, axis=1).reshape(frames, -1), 6) + 0.0,
        end_site_parents=np.array(leaves, dtype=np.int64),
        end_site_offsets=np.array([_end_site(skeleton, j, solved.offsets) for j in leaves]) * CM_PER_METRE,
    )


def joints_to_bvh(joints: np.ndarray, skeleton: Skeleton | str = SMPL22, fps: float = FPS) -> str:
    """The text of a BVH file (see the module docstring for names, units and channels) animating `joints`."""
    return write_bvh(None, joints_to_bvh_motion(joints, skeleton, fps), precision=_PRECISION)
