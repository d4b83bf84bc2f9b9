"""Turn a BVH skeleton's motion into SMPL-22 joint positions (HumanML3D's skeleton), in metres, 20 fps, normalised.

Retargeting here is positional: forward kinematics gives world joint positions, a `JointMap` picks (or blends) the
source joints that sit where the SMPL-22 joints sit, and `motion.features.normalize_joints` then re-imposes the
reference bone lengths, puts the feet on the floor and turns the first frame to face +Z. That is exactly the
HumanML3D processing, so a converted clip is interchangeable with HumanML3D's own joints.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TypeAlias

import numpy as np

from t2m.motion.bvh import BvhMotion
from t2m.motion.constants import FPS
from t2m.motion.features import normalize_joints
from t2m.motion.skeleton import SMPL22
from t2m.motion.transforms import resample

__all__ = ["BANDAI_NAMCO", "CC_RIG", "JointMap", "bvh_to_smpl22", "clean_fps", "map_positions"]

# One entry per target joint: a source joint name, or {source name: weight} for a synthesised joint.
TargetSpec: TypeAlias = str | Mapping[str, float]


@dataclass(frozen=True)
class JointMap:
    """Where each target (SMPL-22) joint comes from in a source BVH skeleton.

    `sources[i]` is a tuple of (source joint name, weight) pairs whose weighted mean is target joint i: one pair
    for a joint that exists in the source, several for a synthesised joint (e.g. SMPL's spine2 as the midpoint of
    two source spine joints). `units_to_metres` converts the file's units (0.01 for centimetres).
    """

    name: str
    target_names: tuple[str, ...]
    sources: tuple[tuple[tuple[str, float], ...], ...]
    units_to_metres: float = 1.0

    def __post_init__(self) -> None:
        if len(self.target_names) != len(self.sources):
            raise ValueError(f"JointMap {self.name!r}: {len(self.target_names)} target names "
                             f"but {len(self.sources)} source entries")
        for target, pairs in zip(self.target_names, self.sources):
            if not pairs or not np.isclose(sum(w for _, w in pairs), 1.0):
                raise ValueError(f"JointMap {self.name!r}: weights for {target!r} must be non-empty and sum to 1")
        if not self.units_to_metres > 0:
            raise ValueError(f"JointMap {self.name!r}: units_to_metres must be positive")

    @classmethod
    def from_targets(cls, name: str, targets: Sequence[tuple[str, TargetSpec]], units_to_metres: float) -> JointMap:
        """Build from [(target joint name, source name | {source: weight}), ...] in target joint order."""
        names: list[str] = []
        sources: list[tuple[tuple[str, float], ...]] = []
        for target, spec in targets:
            names.append(target)
            if isinstance(spec, str):
                sources.append(((spec, 1.0),))
            else:
                sources.append(tuple((str(k), float(v)) for k, v in spec.items()))
        return cls(name=name, target_names=tuple(names), sources=tuple(sources), units_to_metres=units_to_metres)

    @property
    def source_names(self) -> set[str]:
        return {source for pairs in self.sources for source, _ in pairs}

    def weights(self, joint_names: Sequence[str]) -> np.ndarray:
        """Matrix W [targets, source joints] with target positions = W @ source positions."""
        index = {name: i for i, name in enumerate(joint_names)}
        missing = sorted(self.source_names - set(index))
        if missing:
            raise ValueError(f"BVH skeleton does not match joint map {self.name!r}: missing joints "
                             f"{', '.join(missing)} (the file has {', '.join(joint_names)})")
        matrix = np.zeros((len(self.sources), len(joint_names)))
        for target, pairs in enumerate(self.sources):
            for source, weight in pairs:
                matrix[target, index[source]] += weight
        return matrix


# SMPL-22 order (docs/data.md). Bandai-Namco's `joint_Root` is a ground-level helper, not a body joint.
# Handedness checked on the data: with the character walking toward +Z the `_L` joints are at +x, i.e. `_L` is
# the character's own left, as SMPL's left (tests/motion/test_retarget.py checks it on real clips).
BANDAI_NAMCO = JointMap.from_targets("bandai-namco", [
    ("pelvis", "Hips"),
    ("left_hip", "UpperLeg_L"),
    ("right_hip", "UpperLeg_R"),
    ("spine1", "Spine"),
    ("left_knee", "LowerLeg_L"),
    ("right_knee", "LowerLeg_R"),
    ("spine2", {"Spine": 0.5, "Chest": 0.5}),   # SMPL has three spine joints where this skeleton has two
    ("left_ankle", "Foot_L"),
    ("right_ankle", "Foot_R"),
    ("spine3", "Chest"),
    ("left_foot", "Toes_L"),
    ("right_foot", "Toes_R"),
    ("neck", "Neck"),
    ("left_collar", "Shoulder_L"),
    ("right_collar", "Shoulder_R"),
    ("head", "Head"),
    ("left_shoulder", "UpperArm_L"),
    ("right_shoulder", "UpperArm_R"),
    ("left_elbow", "LowerArm_L"),
    ("right_elbow", "LowerArm_R"),
    ("left_wrist", "Hand_L"),
    ("right_wrist", "Hand_R"),
], units_to_metres=0.01)


# Reallusion Character Creator's rig (the CMU conversions of IClone-CMU-Mocap): root `RL_BoneRoot` on the floor,
# body root `CC_Base_Hip`, about 100 joints with twist, finger, toe and face bones, centimetres. Heights above the
# hip in its rest pose: Waist 8 cm, Spine01 12, Spine02 27, Clavicles 47, NeckTwist01 54, Head 62; SMPL's spine1,
# spine2, spine3, neck and head sit 13, 28, 33, 55 and 65 cm above its pelvis, so spine3 is put a quarter of the
# way from Spine02 to the neck. `_L` is the character's own left (at +x when the body faces +z, checked on 02_01).
CC_RIG = JointMap.from_targets("cc-rig", [
    ("pelvis", "CC_Base_Hip"),
    ("left_hip", "CC_Base_L_Thigh"),
    ("right_hip", "CC_Base_R_Thigh"),
    ("spine1", "CC_Base_Spine01"),
    ("left_knee", "CC_Base_L_Calf"),
    ("right_knee", "CC_Base_R_Calf"),
    ("spine2", "CC_Base_Spine02"),
    ("left_ankle", "CC_Base_L_Foot"),
    ("right_ankle", "CC_Base_R_Foot"),
    ("spine3", {"CC_Base_Spine02": 0.75, "CC_Base_NeckTwist01": 0.25}),
    ("left_foot", "CC_Base_L_ToeBase"),
    ("right_foot", "CC_Base_R_ToeBase"),
    ("neck", "CC_Base_NeckTwist01"),
    ("left_collar", "CC_Base_L_Clavicle"),
    ("right_collar", "CC_Base_R_Clavicle"),
    ("head", "CC_Base_Head"),
    ("left_shoulder", "CC_Base_L_Upperarm"),
    ("right_shoulder", "CC_Base_R_Upperarm"),
    ("left_elbow", "CC_Base_L_Forearm"),
    ("right_elbow", "CC_Base_R_Forearm"),
    ("left_wrist", "CC_Base_L_Hand"),
    ("right_wrist", "CC_Base_R_Hand"),
], units_to_metres=0.01)


def map_positions(bvh: BvhMotion, joint_map: JointMap = BANDAI_NAMCO) -> np.ndarray:
    """World positions of the target joints [T, targets, 3] in metres, at the file's frame rate (not normalised)."""
    positions = bvh.forward_kinematics()
    mapped = np.einsum("kj,tjc->tkc", joint_map.weights(bvh.joint_names), positions)
    return mapped * joint_map.units_to_metres


def clean_fps(fps: float) -> float:
    """BVH frame times are printed rounded (0.0333333); snap to the whole rate they stand for."""
    return float(round(fps)) if abs(fps - round(fps)) < 1e-3 else fps


def bvh_to_smpl22(bvh: BvhMotion, joint_map: JointMap = BANDAI_NAMCO, target_fps: float = FPS) -> np.ndarray:
    """FK -> joint map -> metres -> resample to `target_fps` -> HumanML3D normalisation. Returns float32 [T, 22, 3]."""
    if len(joint_map.target_names) != len(SMPL22.joint_names):
        raise ValueError(f"joint map {joint_map.name!r} has {len(joint_map.target_names)} targets, "
                         f"SMPL-22 needs {len(SMPL22.joint_names)}")
    if bvh.num_frames < 2:
        raise ValueError(f"BVH has {bvh.num_frames} frame(s); a motion needs at least 2")
    joints = map_positions(bvh, joint_map)
    source_fps = clean_fps(bvh.fps)
    if source_fps != target_fps:
        joints = resample(joints, source_fps, target_fps)
    return np.asarray(normalize_joints(joints, SMPL22), dtype=np.float32)
