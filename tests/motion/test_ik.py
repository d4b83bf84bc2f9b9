"""motion.ik: positions -> rotations must reproduce the joints at any heading and choose twists sensibly."""
from __future__ import annotations

import numpy as np
import pytest

from t2m.motion.ik import joints_to_rotations, motion_offsets, rotations_to_joints
from t2m.motion.quaternion import qfrom_axis_angle, qmul
from t2m.motion.skeleton import SMPL22
from t2m.motion.transforms import mirror_joints
from tests.headings import full_turn, yaw

NAMES = SMPL22.joint_names


def reconstruct(joints: np.ndarray) -> tuple[np.ndarray, object]:
    solved = joints_to_rotations(joints)
    return rotations_to_joints(*solved, SMPL22.parents), solved


@pytest.fixture(scope="module")
def sample(humanml3d_sample) -> np.ndarray:
    return humanml3d_sample["joints"].astype(np.float64)


@pytest.mark.parametrize("mirrored", [False, True])
@pytest.mark.parametrize("heading", [0, 90, 180, 270, 33])
def test_fk_reproduces_the_real_sample_at_every_heading(sample, heading, mirrored):
    joints = yaw(mirror_joints(sample) if mirrored else sample, heading)
    positions, solved = reconstruct(joints)
    error = np.linalg.norm(positions - joints, axis=-1)
    assert error.max() < 1e-5, f"max error {error.max():.2e} m"
    np.testing.assert_allclose(np.linalg.norm(solved.local_quats, axis=-1), 1.0, atol=1e-9)


def test_full_turn_within_a_clip_is_reproduced_with_continuous_quaternions(sample):
    joints = full_turn(sample)
    positions, solved = reconstruct(joints)
    assert np.linalg.norm(positions - joints, axis=-1).max() < 1e-5
    consecutive = np.sum(solved.local_quats[1:] * solved.local_quats[:-1], axis=-1)
    assert consecutive.min() > 0, "a joint's quaternion must stay in one hemisphere from frame to frame"
    # the turn adds 360 / 169 degrees a frame: the root's frame-to-frame rotation may differ from the unturned
    # clip's by at most that much (no wrap-around or flip anywhere in the turn)
    base = joints_to_rotations(sample).local_quats[:, 0]
    base_step = 2 * np.degrees(np.arccos(np.clip(np.abs(np.sum(base[1:] * base[:-1], -1)), 0, 1)))
    turned_step = 2 * np.degrees(np.arccos(np.clip(consecutive[:, 0], 0, 1)))
    assert np.max(np.abs(turned_step - base_step)) <= 360.0 / (len(sample) - 1) + 1e-6


def test_turning_the_motion_only_turns_the_root(sample):
    """No world axis is used anywhere: every local rotation but the root's is heading-invariant."""
    base = joints_to_rotations(sample)
    turned = joints_to_rotations(yaw(sample, 137.0))
    same = np.abs(np.sum(base.local_quats[:, 1:] * turned.local_quats[:, 1:], axis=-1))
    assert same.min() > 1 - 1e-8
    heading = qfrom_axis_angle(np.array([0.0, 1.0, 0.0]), np.radians(137.0))
    expected_root = qmul(heading, base.local_quats[:, 0])
    assert np.abs(np.sum(expected_root * turned.local_quats[:, 0], axis=-1)).min() > 1 - 1e-8
    np.testing.assert_allclose(turned.offsets, base.offsets, atol=1e-7)


@pytest.mark.parametrize("joint,axis", [("left_knee", 1.0), ("right_knee", 1.0),
                                        ("left_elbow", -1.0), ("right_elbow", -1.0)])
def test_knees_and_elbows_bend_about_their_hinge(sample, joint, axis):
    """The twist of hips/shoulders follows the limb's bend plane, so the middle joint is a pure hinge about x."""
    quats = joints_to_rotations(sample).local_quats[:, NAMES.index(joint)]
    angle = 2 * np.degrees(np.arccos(np.clip(np.abs(quats[:, 0]), 0, 1)))
    bent = angle > 10
    assert bent.sum() > 20, "the sample should bend this joint in many frames"
    rotation_axis = quats[bent, 1:] * np.sign(quats[bent, :1])
    rotation_axis /= np.linalg.norm(rotation_axis, axis=-1, keepdims=True)
    assert np.min(rotation_axis[:, 0] * axis) > 0.999  # knees flex about +x, elbows about -x


def test_leaves_keep_the_parents_twist(sample):
    quats = joints_to_rotations(sample).local_quats
    for leaf in ("head", "left_wrist", "right_wrist", "left_foot", "right_foot"):
        np.testing.assert_allclose(np.abs(quats[:, NAMES.index(leaf), 0]), 1.0, atol=1e-12)


def test_offsets_keep_the_motions_bone_lengths_and_rest_directions(sample):
    offsets = motion_offsets(sample)
    measured = np.linalg.norm(sample[:, 1:] - sample[:, list(SMPL22.parents[1:])], axis=-1).mean(0)
    np.testing.assert_allclose(np.linalg.norm(offsets[1:], axis=-1), measured, rtol=1e-9)
    single = [j for j in range(1, 22) if SMPL22.parents.count(SMPL22.parents[j]) == 1]
    np.testing.assert_allclose(offsets[single] / measured[np.array(single) - 1, None],
                               SMPL22.rest_directions[single], atol=1e-12)
    # the hips hang below the pelvis in real data: the fitted rest pose keeps that (the raw direction is level)
    assert offsets[NAMES.index("left_hip"), 1] < -0.05


def test_bone_length_wobble_does_not_accumulate_down_the_chains(sample):
    rng = np.random.default_rng(0)
    noisy = sample + rng.normal(scale=0.005, size=sample.shape)
    positions, _ = reconstruct(noisy)
    error = np.linalg.norm(positions - noisy, axis=-1)
    assert error.mean() < 0.01
    # the wrists end chains of 7 bones: aimed from the rebuilt parent, their error stays that of one bone
    assert error[:, [NAMES.index("left_wrist"), NAMES.index("right_wrist")]].mean() < 0.012


@pytest.mark.parametrize("case", ["upside_down", "random", "collapsed", "collinear", "one_frame"])
def test_odd_poses_stay_finite(sample, case):
    rng = np.random.default_rng(1)
    joints = {
        "upside_down": sample * np.array([1.0, -1.0, -1.0]),
        "random": rng.normal(size=(20, 22, 3)),
        "collapsed": np.zeros((4, 22, 3)),
        "collinear": np.tile(np.arange(22.0)[None, :, None] * np.array([0.0, 0.1, 0.0]), (3, 1, 1)),
        "one_frame": sample[:1],
    }[case]
    positions, solved = reconstruct(joints)
    assert np.all(np.isfinite(solved.local_quats)) and np.all(np.isfinite(solved.offsets))
    np.testing.assert_allclose(np.linalg.norm(solved.local_quats, axis=-1), 1.0, atol=1e-9)
    if case != "random":  # rigid inputs come back exactly
        assert np.linalg.norm(positions - joints, axis=-1).max() < 1e-5


def test_bad_input_names_the_problem(sample):
    with pytest.raises(ValueError, match=r"joints must have shape \[frames >= 1, 22, 3\]"):
        joints_to_rotations(sample[:, :21])
    broken = sample.copy()
    broken[5, 3, 1] = np.nan
    with pytest.raises(ValueError, match="frame 5"):
        joints_to_rotations(broken)
