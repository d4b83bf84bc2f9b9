"""Mirroring, resampling and heading on the real HumanML3D sample."""
from __future__ import annotations

import numpy as np
import pytest

from t2m.motion.features import features_to_joints, joints_to_features
from t2m.motion.quaternion import qfrom_axis_angle, qrot
from t2m.motion.skeleton import KIT21, SMPL22
from t2m.motion.transforms import facing_angle, mirror_joints, resample


def test_mirror_twice_is_identity_and_swaps_sides(humanml3d_sample):
    joints = humanml3d_sample["joints"]
    mirrored = mirror_joints(joints, SMPL22)
    assert mirrored.dtype == joints.dtype
    assert np.array_equal(mirror_joints(mirrored, SMPL22), joints)
    left_hip, right_hip = SMPL22.joint_index("left_hip"), SMPL22.joint_index("right_hip")
    assert np.array_equal(mirrored[:, left_hip, 0], -joints[:, right_hip, 0])
    assert np.array_equal(mirrored[:, 0, 1:], joints[:, 0, 1:])
    assert np.array_equal(mirror_joints(mirror_joints(np.ones((2, 21, 3)), KIT21), KIT21), np.ones((2, 21, 3)))


def test_mirrored_features_recover_mirrored_joints(humanml3d_sample):
    """A mirrored normalised clip is still normalised; its features turn the other way and give it back."""
    joints = humanml3d_sample["joints"]
    mirrored = mirror_joints(joints, SMPL22)
    features = joints_to_features(joints)
    mirrored_features = joints_to_features(mirrored)
    assert np.abs(features_to_joints(mirrored_features, with_final_frame=True) - mirrored).max() < 1e-5
    # heading change and sideways root velocity flip sign; height and forward speed do not
    assert np.abs(mirrored_features[:, 0] + features[:, 0]).max() < 1e-5
    assert np.abs(mirrored_features[:, 1] + features[:, 1]).max() < 1e-5
    assert np.abs(mirrored_features[:, 2:4] - features[:, 2:4]).max() < 1e-5
    # contacts swap feet
    assert np.array_equal(mirrored_features[:, 259:261], features[:, 261:263])


def test_facing_angle_sign_and_offset(humanml3d_sample):
    joints = humanml3d_sample["joints"].astype(np.float64)
    angles = facing_angle(joints, SMPL22)
    assert angles.shape == (170,)
    assert abs(angles[0]) < 1e-6  # a normalised clip starts facing +Z
    # SMPL's left is +X when facing +Z
    assert joints[0, SMPL22.joint_index("left_hip"), 0] > joints[0, SMPL22.joint_index("right_hip"), 0]
    # a right-handed (counter-clockwise from above) turn by 0.5 rad, towards the body's left, adds 0.5
    turned = qrot(qfrom_axis_angle(np.array([0.0, 1.0, 0.0]), 0.5), joints)
    difference = np.angle(np.exp(1j * (facing_angle(turned) - angles)))
    assert np.abs(difference - 0.5).max() < 1e-9
    # the mirror turns the other way
    assert np.abs(facing_angle(mirror_joints(joints)) + angles).max() < 1e-9
    # HumanML3D's channel 0 is the rotation that undoes the heading: its running sum (a half angle) is minus half
    # the facing angle (loosely: HumanML3D smooths the facing and weights hips and shoulders differently)
    heading = 2 * np.concatenate([[0.0], np.cumsum(humanml3d_sample["features"][:-1, 0])])
    assert np.corrcoef(heading, np.unwrap(angles))[0, 1] < -0.95
    assert np.abs(heading + np.unwrap(angles)).max() < 0.5  # the clip turns through 3.2 rad


def test_resample_30_to_20_keeps_endpoints(humanml3d_sample):
    joints = humanml3d_sample["joints"][:31]
    out = resample(joints, 30, 20)
    assert out.shape == (21, 22, 3) and out.dtype == np.float32
    assert np.array_equal(out[0], joints[0]) and np.allclose(out[-1], joints[-1])
    assert np.allclose(out[1], (joints[1] + joints[2]) / 2, atol=1e-7)  # t = 0.05 s sits between frames 1 and 2


@pytest.mark.parametrize("frames, src, dst, expected", [(21, 20, 10, 11), (11, 10, 20, 21), (7, 20, 20, 7),
                                                        (32, 30, 20, 21), (1, 30, 20, 1)])
def test_resample_frame_counts(frames, src, dst, expected):
    time = np.arange(frames, dtype=np.float64) / src
    signal = np.stack([time, 2 * time + 1], axis=-1)  # linear: interpolation is exact
    out = resample(signal, src, dst)
    assert out.shape == (expected, 2)
    assert np.allclose(out[:, 0], np.arange(expected) / dst)
    assert np.allclose(out[:, 1], 2 * out[:, 0] + 1)


def test_resample_rejects_bad_rates():
    with pytest.raises(ValueError, match="frame rates must be positive"):
        resample(np.zeros((3, 22, 3)), 0, 20)
    with pytest.raises(ValueError, match="at least one frame"):
        resample(np.zeros((0, 22, 3)), 30, 20)
