"""HumanML3D features <-> joints on the real sample 012314, plus normalisation and input checks."""
from __future__ import annotations

from itertools import pairwise

import numpy as np
import pytest

from t2m.motion.features import (
    JointRecovery,
    feature_dim,
    features_to_joints,
    forward_kinematics,
    joints_to_features,
    normalize_joints,
    validate_features,
    validate_joints,
)
from t2m.motion.quaternion import qfrom_axis_angle, qrot
from t2m.motion.skeleton import KIT21, SMPL22, get_skeleton
from t2m.motion.transforms import facing_angle

ROOT, RIC, ROTATIONS, VELOCITIES, CONTACTS = (
    slice(0, 4), slice(4, 67), slice(67, 193), slice(193, 259), slice(259, 263)
)
POSITIONAL = np.r_[0:67, 193:259]  # every channel except the 6D rotations and the contacts
SMOOTHING_REACH = 80  # radius of HumanML3D's Gaussian (sigma 20) over the facing direction


def bone_lengths(joints: np.ndarray, skeleton=SMPL22) -> np.ndarray:
    parents = np.array(skeleton.parents[1:])
    return np.linalg.norm(joints[:, 1:] - joints[:, parents], axis=-1)


def test_feature_dims():
    assert feature_dim(SMPL22) == 263
    assert feature_dim(KIT21) == 251
    assert feature_dim("kit21") == 251


def test_recovered_joints_match_humanml3d(humanml3d_sample):
    joints = features_to_joints(humanml3d_sample["features"])
    assert joints.shape == (170, 22, 3) and joints.dtype == np.float32
    error = np.abs(joints - humanml3d_sample["joints"]).max()
    print(f"features -> joints: max error {error:.2e} m")
    assert error < 1e-5


def test_extracted_features_match_humanml3d_on_shared_frames(humanml3d_sample):
    """170 stored joint frames give 169 rows = stored rows 0..168. The facing is smoothed over +-80 frames and the
    original clip's 171st frame is missing here, so only rows out of the smoothing's reach of the end are exact."""
    stored = humanml3d_sample["features"]
    ours = joints_to_features(humanml3d_sample["joints"])
    assert ours.shape == (169, 263)
    shared = stored[:169]
    exact_rows = slice(0, 169 - SMOOTHING_REACH)
    error_exact = np.abs(ours[exact_rows][:, POSITIONAL] - shared[exact_rows][:, POSITIONAL]).max()
    error_all = np.abs(ours[:, POSITIONAL] - shared[:, POSITIONAL]).max(axis=1)  # per row
    within = int((error_all < 1e-3).sum())
    contacts = (ours[:, CONTACTS] == shared[:, CONTACTS]).all(axis=1).mean()
    rotations = np.abs(ours[exact_rows, ROTATIONS] - shared[exact_rows, ROTATIONS]).max()
    print(f"rows 0..{168 - SMOOTHING_REACH}: max error {error_exact:.2e}; rows within 1e-3: {within}/169; "
          f"worst row {error_all.max():.2e}; 6D rotations (same rows) {rotations:.2e}; contacts agree {contacts:.1%}")
    assert error_exact < 1e-5
    assert within >= 130
    assert error_all.max() < 1e-2
    assert contacts >= 0.95


def test_rebuilding_the_last_frame_reproduces_every_channel(humanml3d_sample):
    """With the frame the last row leads to, the joints are the full original clip: all 263 channels of all 170
    rows come back, the 6D rotations included (the IK is HumanML3D's)."""
    stored = humanml3d_sample["features"]
    joints = features_to_joints(stored, with_final_frame=True)
    assert joints.shape == (171, 22, 3)
    ours = joints_to_features(joints)
    assert ours.shape == stored.shape
    errors = {name: float(np.abs(ours[:, part] - stored[:, part]).max())
              for name, part in [("root", ROOT), ("ric", RIC), ("rotations", ROTATIONS), ("velocities", VELOCITIES)]}
    print("features -> joints -> features:", {k: f"{v:.1e}" for k, v in errors.items()})
    assert errors["root"] < 1e-5 and errors["ric"] < 1e-5 and errors["velocities"] < 1e-5
    assert errors["rotations"] < 1e-4
    assert np.array_equal(ours[:, CONTACTS], stored[:, CONTACTS])


def test_joints_features_joints_round_trip_on_a_turned_copy(humanml3d_sample):
    """A clip HumanML3D never saw (the sample yawed, shifted and normalised again) survives joints -> features ->
    joints."""
    turn = qfrom_axis_angle(np.array([0.0, 1.0, 0.0]), 0.7)
    moved = qrot(turn, humanml3d_sample["joints"][::2].astype(np.float64)) + np.array([1.0, 0.3, 2.0])
    joints = normalize_joints(moved)
    back = features_to_joints(joints_to_features(joints), with_final_frame=True)
    assert np.abs(back - joints).max() < 1e-5


def test_normalize_undoes_rotation_translation_and_lift(humanml3d_sample):
    sample = humanml3d_sample["joints"]
    rng = np.random.default_rng(7)
    for _ in range(3):
        turn = qfrom_axis_angle(np.array([0.0, 1.0, 0.0]), rng.uniform(-np.pi, np.pi))
        shift = rng.uniform(-5, 5, size=3)
        moved = qrot(turn, sample.astype(np.float64)) + shift
        normalised = normalize_joints(moved)
        assert normalised.dtype == np.float32
        assert np.abs(normalised - sample).max() < 1e-4
    assert abs(normalize_joints(sample)[..., 1].min()) < 1e-6


def test_normalize_imposes_reference_bone_lengths(humanml3d_sample):
    """A bigger person with a stretched forearm comes back on the reference skeleton, feet on the floor, at the
    origin, facing +Z."""
    sample = humanml3d_sample["joints"].astype(np.float64)
    bigger = sample * 1.2 + np.array([0.4, 0.1, -0.3])
    stretch = bigger[:, 20] - bigger[:, 18]  # left wrist away from the left elbow
    bigger[:, 20] += 0.3 * stretch
    normalised = normalize_joints(bigger)
    assert np.abs(bone_lengths(normalised) - SMPL22.bone_lengths[1:]).max() < 1e-5
    assert abs(normalised[..., 1].min()) < 1e-6
    assert np.abs(normalised[0, 0, [0, 2]]).max() < 1e-6
    assert abs(facing_angle(normalised[:1])[0]) < 1e-6
    # the root trajectory scales with the legs, so apart from the forearm the sample comes back
    assert np.abs(np.delete(normalised, [20], axis=1) - np.delete(sample, [20], axis=1)).max() < 1e-4


def test_reference_skeleton_matches_the_sample(humanml3d_sample):
    measured = np.median(bone_lengths(humanml3d_sample["joints"].astype(np.float64)), axis=0)
    assert np.abs(measured - SMPL22.bone_lengths[1:]).max() < 1e-6


def test_kit21_round_trip_on_synthetic_motion():
    """KIT-21 (251 dims) has no sample here: animate its rest pose with FK and check features -> joints."""
    rng = np.random.default_rng(3)
    frames = 60
    time = np.linspace(0, 1, frames)[:, None]
    axes = rng.normal(size=(1, KIT21.num_joints, 3))
    local = qfrom_axis_angle(axes, 0.3 * np.sin(6 * time + rng.uniform(0, 6, (1, 21))))
    local[:, 0] = qfrom_axis_angle(np.array([0.0, 1.0, 0.0]), 1.5 * time[:, 0])
    root = np.concatenate([np.sin(time), 1.0 + 0.02 * np.cos(9 * time), 2 * time], axis=1)
    joints = normalize_joints(forward_kinematics(local, root, KIT21), "kit21")
    features = joints_to_features(joints, KIT21)
    assert features.shape == (frames - 1, 251)
    back = features_to_joints(features, KIT21, with_final_frame=True)
    assert np.abs(back - joints).max() < 1e-5


def test_joints_recovered_in_pieces_equal_the_whole_recovery_bit_for_bit():
    """Streaming recovers joints while the motion is still decoded: a frame must not depend on later rows, and the
    running sums (heading, root) continued across pieces must add in the same order as one pass does."""
    features = np.random.default_rng(3).normal(0.0, 0.3, (240, 263))
    whole = features_to_joints(features)
    recovery = JointRecovery(SMPL22)
    pieces = [recovery.push(features[start:end]) for start, end in pairwise([0, 1, 5, 88, 89, 200, 240])]
    assert np.array_equal(np.concatenate(pieces).astype(np.float32), whole)
    # a change from row 150 on leaves the frames before 150 as they were
    changed = features.copy()
    changed[150:] += 1.0
    assert np.array_equal(features_to_joints(changed)[:150], whole[:150])
    assert not np.array_equal(features_to_joints(changed)[150], whole[150])


@pytest.mark.parametrize(
    "bad, message",
    [
        (np.zeros((10, 262)), r"features must have shape \[T, 263\] with T >= 1, got \(10, 262\)"),
        (np.zeros((263,)), r"features must have shape \[T, 263\] with T >= 1, got \(263,\)"),
        (np.zeros((0, 263)), r"with T >= 1, got \(0, 263\)"),
    ],
)
def test_bad_feature_shapes_are_named(bad, message):
    with pytest.raises(ValueError, match=message):
        features_to_joints(bad)


def test_bad_joint_shapes_and_values_are_named():
    with pytest.raises(ValueError, match=r"joints must have shape \[T, 22, 3\] with T >= 2, got \(5, 21, 3\)"):
        joints_to_features(np.zeros((5, 21, 3)))
    with pytest.raises(ValueError, match=r"with T >= 2, got \(1, 22, 3\)"):
        joints_to_features(np.zeros((1, 22, 3)))
    with pytest.raises(ValueError, match=r"joints must have shape \[T, 21, 3\]"):
        normalize_joints(np.zeros((5, 22, 3)), "kit21")
    joints = np.zeros((4, 22, 3))
    joints[2, 5, 1] = np.nan
    with pytest.raises(ValueError, match=r"joints contain NaN or inf \(first at index \(2, 5, 1\)\)"):
        validate_joints(joints)
    features = np.zeros((3, 263))
    features[1, 7] = np.inf
    with pytest.raises(ValueError, match="features contain NaN or inf"):
        features_to_joints(features)
    with pytest.raises(ValueError, match="unknown skeleton 'smpl24'"):
        get_skeleton("smpl24")
    with pytest.raises(ValueError, match="must be numeric"):
        validate_features(np.array([["a"] * 263]))


def test_degenerate_pose_is_a_value_error():
    with pytest.raises(ValueError, match="facing"):
        joints_to_features(np.zeros((5, 22, 3)))


def test_numpy_gaussian_matches_scipy():
    """HumanML3D smooths the facing with scipy's gaussian_filter1d; ours must be the same filter."""
    ndimage = pytest.importorskip("scipy.ndimage")
    from t2m.motion.features import gaussian_smooth

    values = np.random.default_rng(5).normal(size=(37, 3))  # shorter than the kernel radius: edges matter
    expected = ndimage.gaussian_filter1d(values, 20, axis=0, mode="nearest")
    assert np.abs(gaussian_smooth(values, 20) - expected).max() < 1e-12
