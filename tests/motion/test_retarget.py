"""motion.retarget on real Bandai-Namco clips: the converted joints obey HumanML3D's conventions and the labels'
directions (walk goes +Z, walk-back -Z, left hip at +x, left turns turn left, the left hand waves)."""
from __future__ import annotations

import functools

import numpy as np
import pytest

from t2m.motion.bvh import read_bvh
from t2m.motion.features import features_to_joints, joints_to_features
from t2m.motion.retarget import BANDAI_NAMCO, JointMap, bvh_to_smpl22, map_positions
from t2m.motion.skeleton import SMPL22
from t2m.motion.transforms import facing_angle

CONVERTED = ["dataset-1_walk_normal_001", "dataset-1_walk-back_active_001", "dataset-1_bow_normal_001",
             "dataset-2_walk-turn-left_active_041", "dataset-2_wave-left-hand_youthful_007",
             "dataset-2_raise-up-right-hand_active_033"]
FEET = [7, 8, 10, 11]
L_HIP, R_HIP, L_WRIST, R_WRIST = 1, 2, 20, 21


@pytest.fixture(scope="module")
def convert(bandai_clip):
    @functools.cache
    def run(stem: str) -> np.ndarray:
        return bvh_to_smpl22(read_bvh(bandai_clip(stem)), BANDAI_NAMCO, target_fps=20)
    return run


@pytest.mark.parametrize("stem", CONVERTED)
def test_converted_clip_follows_humanml3d_conventions(convert, bandai_clip, stem: str) -> None:
    joints = convert(stem)
    source_frames = read_bvh(bandai_clip(stem)).num_frames
    assert joints.shape == ((source_frames - 1) * 2 // 3 + 1, 22, 3) and joints.dtype == np.float32
    bones = np.linalg.norm(joints[:, 1:] - joints[:, list(SMPL22.parents[1:])], axis=-1)
    np.testing.assert_allclose(bones, np.broadcast_to(SMPL22.bone_lengths[1:], bones.shape), atol=1e-3)
    assert abs(joints[:, FEET, 1].min()) < 0.01                      # lowest foot on the floor
    np.testing.assert_allclose(joints[0, 0, [0, 2]], 0.0, atol=1e-6)  # starts at the origin
    assert abs(np.degrees(facing_angle(joints[:1], SMPL22)[0])) < 5.0  # first frame faces +Z
    assert joints[0, L_HIP, 0] > 0.05 > -0.05 > joints[0, R_HIP, 0]   # left hip on the +x side
    recovered = features_to_joints(joints_to_features(joints, SMPL22), SMPL22)
    np.testing.assert_allclose(recovered, joints[:-1], atol=1e-4)


def test_walk_advances_along_plus_z(convert) -> None:
    joints = convert("dataset-1_walk_normal_001")
    travel = joints[-1, 0] - joints[0, 0]
    assert travel[2] > 3.0 and abs(travel[0]) < 0.25 * travel[2]


def test_walk_back_moves_toward_minus_z(convert) -> None:
    joints = convert("dataset-1_walk-back_active_001")
    travel = joints[-1, 0] - joints[0, 0]
    assert travel[2] < -3.0 and abs(travel[0]) < 0.25 * abs(travel[2])
    assert abs(np.degrees(facing_angle(joints, SMPL22)).mean()) < 20  # still facing +Z: walking backwards


@pytest.mark.parametrize("stem, sign", [("dataset-2_walk-turn-left_active_041", +1),
                                        ("dataset-2_walk-turn-right_active_039", -1)])
def test_turn_labels_match_the_heading_change(convert, stem: str, sign: int) -> None:
    heading = np.degrees(np.unwrap(facing_angle(convert(stem), SMPL22)))
    turn = heading[-10:].mean() - heading[:10].mean()
    assert 45 < sign * turn < 135, turn  # positive heading change = turning toward +x = the body's left


def test_the_labelled_hand_is_the_one_that_moves(convert) -> None:
    def wrist_travel(joints: np.ndarray, wrist: int) -> float:
        return float(np.linalg.norm(np.diff(joints[:, wrist], axis=0), axis=-1).sum())
    waving = convert("dataset-2_wave-left-hand_youthful_007")
    assert wrist_travel(waving, L_WRIST) > 2 * wrist_travel(waving, R_WRIST)
    raising = convert("dataset-2_raise-up-right-hand_active_033")
    assert raising[:, R_WRIST, 1].max() > raising[:, L_WRIST, 1].max() + 0.3


def test_spine2_is_synthesised_between_spine_and_chest(bandai_clip) -> None:
    bvh = read_bvh(bandai_clip("dataset-1_bow_normal_001"))
    mapped = map_positions(bvh, BANDAI_NAMCO)
    world = bvh.forward_kinematics() * 0.01
    spine, chest = bvh.joint_index("Spine"), bvh.joint_index("Chest")
    np.testing.assert_allclose(mapped[:, 6], (world[:, spine] + world[:, chest]) / 2, atol=1e-12)
    np.testing.assert_allclose(mapped[:, 0], world[:, bvh.joint_index("Hips")], atol=1e-12)
    assert "joint_Root" not in BANDAI_NAMCO.source_names
    assert BANDAI_NAMCO.target_names == SMPL22.joint_names


def test_joint_map_errors_name_the_problem(bandai_clip) -> None:
    bvh = read_bvh(bandai_clip("dataset-1_bow_normal_001"))
    other = JointMap.from_targets("other", [(name, "Pelvis") for name in SMPL22.joint_names], units_to_metres=0.01)
    with pytest.raises(ValueError, match="missing joints Pelvis"):
        bvh_to_smpl22(bvh, other)
    with pytest.raises(ValueError, match="weights for 'spine2' must"):
        JointMap.from_targets("bad", [("spine2", {"Spine": 0.5, "Chest": 0.6})], units_to_metres=1.0)
    short = JointMap.from_targets("short", [("pelvis", "Hips")], units_to_metres=0.01)
    with pytest.raises(ValueError, match="SMPL-22 needs 22"):
        bvh_to_smpl22(bvh, short)
