"""motion.bvh_export: the BVH we write must read back (motion.bvh FK) to the joints, whatever the heading."""
from __future__ import annotations

import numpy as np
import pytest

from t2m.motion.bvh import read_bvh
from t2m.motion.bvh_export import BVH_NAMES, JOINT_CHANNELS, ROOT_CHANNELS, bvh_joint_names, joints_to_bvh
from t2m.motion.skeleton import SMPL22
from t2m.motion.transforms import mirror_joints
from tests.headings import full_turn, yaw

MIXAMO = ["Hips", "LeftUpLeg", "RightUpLeg", "Spine", "LeftLeg", "RightLeg", "Spine1", "LeftFoot", "RightFoot",
          "Spine2", "LeftToe", "RightToe", "Neck", "LeftShoulder", "RightShoulder", "Head", "LeftArm", "RightArm",
          "LeftForeArm", "RightForeArm", "LeftHand", "RightHand"]


@pytest.fixture(scope="module")
def sample(humanml3d_sample) -> np.ndarray:
    return humanml3d_sample["joints"].astype(np.float64)


def read_back(text: str) -> np.ndarray:
    """Joints [T, 22, 3] in metres, SMPL order, from the file's own forward kinematics."""
    bvh = read_bvh(text)
    order = [bvh.joint_index(name) for name in bvh_joint_names(SMPL22)]
    return bvh.forward_kinematics()[:, order] / 100.0


@pytest.mark.parametrize("mirrored", [False, True])
@pytest.mark.parametrize("heading", [0, 90, 180, 270, 45, -123])
def test_round_trip_reproduces_the_real_sample(sample, heading, mirrored):
    joints = yaw(mirror_joints(sample) if mirrored else sample, heading)
    error = np.linalg.norm(read_back(joints_to_bvh(joints)) - joints, axis=-1)
    assert error.mean() < 1e-5 and error.max() < 1e-4, f"mean {error.mean():.2e} m, max {error.max():.2e} m"


def test_full_turn_round_trips_and_its_heading_channel_is_unwrapped(sample):
    joints = full_turn(sample)
    text = joints_to_bvh(joints)
    assert np.linalg.norm(read_back(text) - joints, axis=-1).max() < 1e-4
    bvh = read_bvh(text)
    heading = bvh.motion[:, bvh.channel_starts[bvh.joint_index("Hips")] + ROOT_CHANNELS.index("Yrotation")]
    steps = np.abs(np.diff(heading))
    assert steps.max() < 45.0, "no 360-degree wrap between frames"
    base = read_bvh(joints_to_bvh(sample))
    base_heading = base.motion[:, base.channel_starts[0] + ROOT_CHANNELS.index("Yrotation")]
    # the turn adds 360 degrees of heading over the clip (up to the pitch/roll the Euler split leaves)
    assert abs((heading[-1] - heading[0]) - (base_heading[-1] - base_heading[0]) - 360.0) < 1.0


def test_file_layout(sample):
    bvh = read_bvh(joints_to_bvh(sample, fps=20))
    assert sorted(bvh.joint_names) == sorted(MIXAMO) and bvh.joint_names[0] == "Hips"
    assert [BVH_NAMES[n] for n in SMPL22.joint_names] == MIXAMO
    assert bvh.num_frames == len(sample) and bvh.frame_time == pytest.approx(0.05)
    assert bvh.channels[0] == ROOT_CHANNELS and all(c == JOINT_CHANNELS for c in bvh.channels[1:])
    np.testing.assert_array_equal(bvh.offsets[0], 0.0)
    ends = sorted(bvh.joint_names[p] for p in bvh.end_site_parents)
    assert ends == ["Head", "LeftHand", "LeftToe", "RightHand", "RightToe"]
    # centimetres: the left shin of this sample is 43.2 cm long
    shin = np.linalg.norm(bvh.offsets[bvh.joint_index("LeftFoot")])
    assert shin == pytest.approx(100 * np.linalg.norm(sample[:, 7] - sample[:, 4], axis=-1).mean(), abs=1e-4)
    # the root's position channels are the pelvis position in cm
    np.testing.assert_allclose(bvh.motion[:, :3], sample[:, 0] * 100.0, atol=1e-4)  # 7 significant digits


def test_frame_time_follows_fps(sample):
    assert read_bvh(joints_to_bvh(sample[:10], fps=30)).frame_time == pytest.approx(1 / 30)


def test_bad_input_is_a_value_error(sample):
    with pytest.raises(ValueError, match="fps"):
        joints_to_bvh(sample, fps=0)
    with pytest.raises(ValueError, match="joints must have shape"):
        joints_to_bvh(sample[0])
