"""DeepMimic `humanoid3d` joints -> SMPL-22 joint positions, with the joints the humanoid lacks filled in.

The humanoid has a pelvis (root), one chest joint, a neck, hips, knees, ankles, shoulders, elbows and wrists. SMPL-22
also has three spine joints, two collars, a head and two toe bases. Each filled joint is a point fixed in the frame
of a humanoid body, so it moves rigidly with it (numbers in metres, humanoid rest frame: x forward, y up, z right):

- spine1: halfway between the root and the chest joint (the root's body is rigid, so this is exact interpolation);
- spine2: the chest joint itself (0.236 m above the root, where SMPL's spine2 sits, 0.28 m above its pelvis);
- spine3: a quarter of the way from the chest joint to the neck joint, in the chest's frame (SMPL's spine3 is
  0.06 m above spine2, a fifth of the way to its neck);
- collars: in the chest's frame, at 90% of the shoulder's height and 40% of its sideways offset (about 7 cm off
  the midline, level with the base of the neck, where SMPL's collars are);
- neck: the neck joint; head: 0.1 m up the neck's own y axis (the head's sphere is centred 0.175 m up it);
- toe bases (SMPL's `*_foot`): in the ankle's frame, 0.12 m forward and 0.045 m down, the front of the sole of the
  humanoid's foot box, so the toe follows every ankle rotation (heel raises, pointed feet).
Bone lengths are then re-imposed by `features.normalize_joints`, so only the directions of the filled bones matter.
"""
from __future__ import annotations

import numpy as np

from t2m.motion.constants import FPS
from t2m.motion.deepmimic import HUMANOID3D, DeepMimicMotion
from t2m.motion.features import normalize_joints
from t2m.motion.quaternion import qrot
from t2m.motion.retarget import clean_fps
from t2m.motion.skeleton import SMPL22
from t2m.motion.transforms import resample

__all__ = ["FILLED_JOINTS", "deepmimic_to_smpl22", "humanoid3d_positions"]

SPINE1_FRACTION = 0.5
SPINE3_FRACTION = 0.25
COLLAR_SCALE = np.array([1.0, 0.9, 0.4])
HEAD_UP = np.array([0.0, 0.1, 0.0])
TOE_OFFSET = np.array([0.12, -0.045, 0.0])
FILLED_JOINTS = ("spine1", "spine3", "left_collar", "right_collar", "head", "left_foot", "right_foot")

# SMPL-22 joints that are humanoid3d joints as they are
_DIRECT = {"pelvis": "root", "left_hip": "left_hip", "right_hip": "right_hip", "left_knee": "left_knee",
           "right_knee": "right_knee", "spine2": "chest", "left_ankle": "left_ankle", "right_ankle": "right_ankle",
           "neck": "neck", "left_shoulder": "left_shoulder", "right_shoulder": "right_shoulder",
           "left_elbow": "left_elbow", "right_elbow": "right_elbow", "left_wrist": "left_wrist",
           "right_wrist": "right_wrist"}


def _at(motion: DeepMimicMotion, body: str, local: np.ndarray) -> np.ndarray:
    """World position [T, 3] of a point fixed at `local` in the frame of the humanoid joint `body`."""
    j = motion.character.index(body)
    return motion.positions[:, j] + qrot(motion.rotations[:, j], np.broadcast_to(local, motion.positions[:, j].shape))


def humanoid3d_positions(motion: DeepMimicMotion) -> np.ndarray:
    """SMPL-22 joint positions [T, 22, 3] in metres at the motion's own rate (not normalised)."""
    if motion.character.names != HUMANOID3D.names:
        raise ValueError(f"DeepMimic character has joints {', '.join(motion.character.names)}; "
                         f"expected humanoid3d's {', '.join(HUMANOID3D.names)}")
    char = motion.character
    out = np.zeros((motion.num_frames, len(SMPL22.joint_names), 3))
    for target, source in _DIRECT.items():
        out[:, SMPL22.joint_index(target)] = motion.positions[:, char.index(source)]
    out[:, SMPL22.joint_index("spine1")] = _at(motion, "root", SPINE1_FRACTION * char.offsets[char.index("chest")])
    out[:, SMPL22.joint_index("spine3")] = _at(motion, "chest", SPINE3_FRACTION * char.offsets[char.index("neck")])
    for side in ("left", "right"):
        shoulder = char.offsets[char.index(f"{side}_shoulder")]
        out[:, SMPL22.joint_index(f"{side}_collar")] = _at(motion, "chest", COLLAR_SCALE * shoulder)
        out[:, SMPL22.joint_index(f"{side}_foot")] = _at(motion, f"{side}_ankle", TOE_OFFSET)
    out[:, SMPL22.joint_index("head")] = _at(motion, "neck", HEAD_UP)
    return out


def deepmimic_to_smpl22(motion: DeepMimicMotion, target_fps: float = FPS, normalize: bool = True) -> np.ndarray:
    """Fill -> resample to `target_fps` -> (HumanML3D normalisation). Returns float32 [T, 22, 3]."""
    joints = humanoid3d_positions(motion)
    fps = clean_fps(motion.fps)
    if fps != target_fps:
        joints = resample(joints, fps, target_fps)
    return np.asarray(normalize_joints(joints, SMPL22) if normalize else joints, dtype=np.float32)
