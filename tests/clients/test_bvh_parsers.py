"""Independent BVH parsers from PyPI read our files: `bvh` (raw channels) and `bvhio` (hierarchy + FK)."""
from __future__ import annotations

import numpy as np
import pytest

from t2m.motion.bvh import read_bvh
from t2m.motion.bvh_export import bvh_joint_names, joints_to_bvh

pytestmark = pytest.mark.clients


@pytest.fixture(scope="module", params=["turn", "mirrored_backwards"])
def exported(request, motions, tmp_path_factory) -> tuple[np.ndarray, str, str]:
    joints = motions[request.param]
    text = joints_to_bvh(joints, fps=20)
    path = tmp_path_factory.mktemp("bvh") / f"{request.param}.bvh"
    path.write_text(text)
    return joints, text, str(path)


def test_bvh_package_reads_names_frames_and_channel_values(exported):
    bvh = pytest.importorskip("bvh", reason="PyPI package `bvh` not installed (scripts/install_clients.sh)")
    joints, text, _ = exported
    theirs = bvh.Bvh(text)
    ours = read_bvh(text)
    assert theirs.get_joints_names() == ours.joint_names
    assert sorted(theirs.get_joints_names()) == sorted(bvh_joint_names())
    assert theirs.nframes == len(joints) and theirs.frame_time == pytest.approx(0.05)
    for index, name in enumerate(ours.joint_names):
        channels = theirs.joint_channels(name)
        assert tuple(channels) == ours.channels[index]
        start = ours.channel_starts[index]
        values = np.array(theirs.frames_joint_channels(name, channels), dtype=np.float64)
        np.testing.assert_array_equal(values, ours.motion[:, start : start + len(channels)])


def test_bvhio_forward_kinematics_matches_our_joints(exported):
    bvhio = pytest.importorskip("bvhio", reason="PyPI package `bvhio` not installed (scripts/install_clients.sh)")
    joints, _, path = exported
    root = bvhio.readAsHierarchy(path)
    names = bvh_joint_names()
    positions = []
    for frame in range(len(joints)):
        root.loadPose(frame)
        world = {joint.Name: np.array(joint.PositionWorld) for joint, _, _ in root.layout()}
        positions.append([world[name] for name in names])
    error = np.linalg.norm(np.array(positions) / 100.0 - joints, axis=-1)  # bvhio works in file units (cm)
    assert error.mean() < 1e-4 and error.max() < 1e-3, f"mean {error.mean():.2e} m, max {error.max():.2e} m"
