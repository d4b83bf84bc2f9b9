"""motion.bvh: parsing (channel orders, 3/6 channels, End Sites, CRLF/tabs), FK, writing, and precise errors."""
from __future__ import annotations

import io
import itertools
import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from t2m.motion.bvh import BvhError, BvhMotion, read_bvh, write_bvh
from t2m.motion.quaternion import euler_to_quat, quat_to_matrix

# A root with 6 channels, a joint with 3 rotation channels, one End Site. Hand-computable FK:
# frame 0: no rotation -> root (1,2,3), arm (11,2,3), tip (16,2,3)
# frame 1: root Zrotation 90 turns +x into +y -> arm at (1,12,3); arm Zrotation 90 more -> tip offset (5,0,0) points
#          along -x -> tip (-4,12,3)
CHAIN = """HIERARCHY
ROOT base
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT arm
  {
    OFFSET 10 0 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 5 0 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.05
1 2 3 0 0 0 0 0 0
1 2 3 90 0 0 90 0 0
"""


def test_fk_on_a_hand_computable_chain() -> None:
    bvh = read_bvh(CHAIN)
    assert bvh.joint_names == ["base", "arm"]
    assert bvh.parents.tolist() == [-1, 0]
    assert bvh.channels == [("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation"),
                            ("Zrotation", "Xrotation", "Yrotation")]
    assert bvh.num_frames == 2 and bvh.frame_time == 0.05 and bvh.fps == pytest.approx(20.0)
    positions = bvh.forward_kinematics(include_end_sites=True)
    expected = np.array([[[1, 2, 3], [11, 2, 3], [16, 2, 3]],
                         [[1, 2, 3], [1, 12, 3], [-4, 12, 3]]], dtype=float)
    np.testing.assert_allclose(positions, expected, atol=1e-9)
    assert bvh.forward_kinematics().shape == (2, 2, 3)


def _two_joint_text(rotation_order: str, angles: tuple[float, float, float]) -> str:
    channels = " ".join(f"{axis}rotation" for axis in rotation_order)
    values = " ".join(str(a) for a in angles)
    return (f"HIERARCHY\nROOT r\n{{\n OFFSET 0 0 0\n CHANNELS 3 Xposition Yposition Zposition\n"
            f" JOINT j\n {{\n  OFFSET 0 0 0\n  CHANNELS 3 {channels}\n"
            f"  End Site\n  {{\n   OFFSET 1 2 3\n  }}\n }}\n}}\n"
            f"MOTION\nFrames: 1\nFrame Time: 0.0333333\n0 0 0 {values}\n")


@pytest.mark.parametrize("order", ["".join(p) for p in itertools.permutations("XYZ")])
def test_every_rotation_order_is_intrinsic_in_channel_order(order: str) -> None:
    angles = (30.0, -50.0, 70.0)
    bvh = read_bvh(_two_joint_text(order, angles))
    tip = bvh.forward_kinematics(include_end_sites=True)[0, 2]
    # independent oracle: scipy's intrinsic (upper-case) Euler convention, R = R_a(order[0]) R_b R_c
    expected = Rotation.from_euler(order, angles, degrees=True).as_matrix() @ np.array([1.0, 2.0, 3.0])
    np.testing.assert_allclose(tip, expected, atol=1e-9)
    # and the project's quaternion module agrees
    matrix = quat_to_matrix(euler_to_quat(np.array(angles), order))
    np.testing.assert_allclose(tip, matrix @ np.array([1.0, 2.0, 3.0]), atol=1e-9)


def test_three_channel_joints_and_partial_position_channels() -> None:
    text = """HIERARCHY
ROOT hips
{
  OFFSET 5 6 7
  CHANNELS 3 Yrotation Xrotation Zrotation
  JOINT lifted
  {
    OFFSET 1 1 1
    CHANNELS 2 Yposition Xrotation
    JOINT leaf
    {
      OFFSET 0 0 2
      CHANNELS 0
    }
  }
}
MOTION
Frames: 1
Frame Time: 0.1
0 0 0 10 90
"""
    bvh = read_bvh(text)
    assert [len(c) for c in bvh.channels] == [3, 2, 0]
    positions = bvh.forward_kinematics()[0]
    np.testing.assert_allclose(positions[0], [5, 6, 7])          # no position channels: the offset is used
    np.testing.assert_allclose(positions[1], [6, 16, 8])         # Yposition replaces only y of the offset
    np.testing.assert_allclose(positions[2], [6, 14, 8], atol=1e-9)  # Xrotation 90 turns +z into -y


def test_crlf_tabs_and_brace_on_header_line_parse_the_same() -> None:
    reference = read_bvh(CHAIN)
    crlf_tabs = CHAIN.replace("  ", "\t").replace("\n", "\r\n").replace("ROOT base\r\n{", "ROOT base {")
    assert read_bvh(crlf_tabs) == reference
    assert read_bvh(io.StringIO(CHAIN)) == reference


def test_read_write_round_trip_is_exact(tmp_path) -> None:
    bvh = read_bvh(CHAIN)
    path = tmp_path / "chain.bvh"
    write_bvh(path, bvh)
    assert read_bvh(path) == bvh
    stream = io.StringIO()
    write_bvh(stream, bvh)
    assert read_bvh(stream.getvalue()) == bvh


def test_write_reorders_a_non_depth_first_hierarchy() -> None:
    # SMPL-like order: root, then two children, then a grandchild of the first child
    bvh = BvhMotion(joint_names=["root", "a", "b", "a_child"], parents=[-1, 0, 0, 1],
                    offsets=np.arange(12, dtype=float).reshape(4, 3),
                    channels=[("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation"),
                              ("Zrotation", "Xrotation", "Yrotation"), ("Zrotation", "Xrotation", "Yrotation"),
                              ("Zrotation", "Xrotation", "Yrotation")],
                    frame_time=0.05, motion=np.random.default_rng(0).normal(size=(3, 15)) * 30)
    back = read_bvh(write_bvh(None, bvh))
    assert back.joint_names == ["root", "a", "a_child", "b"]
    order = [0, 1, 3, 2]
    np.testing.assert_array_equal(back.forward_kinematics(), bvh.forward_kinematics()[:, order])


def test_round_trip_of_a_real_clip_and_its_layout(bandai_clip) -> None:
    bvh = read_bvh(bandai_clip("dataset-1_walk_normal_001"))
    assert bvh.num_joints == 22 and bvh.joint_names[:3] == ["joint_Root", "Hips", "Spine"]
    assert all(len(c) == 6 for c in bvh.channels) and bvh.num_channels == 132
    assert bvh.frame_time == pytest.approx(0.0333333)
    assert len(bvh.end_site_parents) == 5  # Head, both hands, both toes
    assert read_bvh(write_bvh(None, bvh)) == bvh
    six_digits = read_bvh(write_bvh(None, bvh, precision=6))
    np.testing.assert_allclose(six_digits.forward_kinematics(), bvh.forward_kinematics(), atol=1e-2)
    # position channels replace the offset: Hips' world position is its channel values (root has none)
    hips = bvh.joint_index("Hips")
    start = bvh.channel_starts[hips]
    np.testing.assert_allclose(bvh.forward_kinematics()[:, hips], bvh.motion[:, start:start + 3])


def _error(text: str) -> str:
    with pytest.raises(BvhError) as caught:
        read_bvh(text)
    return str(caught.value)


def _replace_line(text: str, number: int, new: str) -> str:
    lines = text.split("\n")
    lines[number - 1] = new
    return "\n".join(lines)


def test_bad_offset_names_the_line() -> None:
    message = _error(_replace_line(CHAIN, 8, "    OFSET 1 2"))
    assert message == "line 8: expected 'OFFSET x y z', got 'OFSET 1 2'"
    assert _error(_replace_line(CHAIN, 8, "    OFFSET 1 2")).startswith("line 8: expected 'OFFSET x y z'")
    assert "not a number" in _error(_replace_line(CHAIN, 8, "    OFFSET 1 two 3"))


def test_truncated_hierarchy_names_the_end() -> None:
    truncated = "\n".join(CHAIN.split("\n")[:9])  # stops inside joint 'arm'
    message = _error(truncated)
    assert message.startswith("line 10: unexpected end of file, expected")
    assert "'arm'" in message


def test_missing_motion_section() -> None:
    hierarchy_only = CHAIN.split("MOTION")[0]
    assert "expected 'MOTION'" in _error(hierarchy_only)
    assert _error(CHAIN.replace("MOTION", "MOTIONS")).startswith("line 16: expected")


def test_wrong_value_count_names_frame_and_line() -> None:
    text = CHAIN.replace("1 2 3 90 0 0 90 0 0", "1 2 3 90 0 0 90 0")
    assert _error(text) == "MOTION: frame 1 (line 20) has 8 values, expected 9"


def test_non_numeric_value_names_the_line() -> None:
    message = _error(CHAIN.replace("1 2 3 90 0 0 90 0 0", "1 2 3 90 x 0 90 0 0"))
    assert message == "line 20: MOTION frame 1 has a non-numeric value 'x'"


def test_frame_count_and_header_problems() -> None:
    assert _error(CHAIN.replace("Frames: 2", "Frames: 3")) == "MOTION: 'Frames: 3' (line 17) but 2 frame lines follow"
    assert _error(CHAIN.replace("Frames: 2", "Frames: two")).startswith("line 17: expected 'Frames: n'")
    assert _error(CHAIN.replace("Frame Time: 0.05", "Frame Time: 0")).startswith("line 18: frame time must be")
    assert _error(CHAIN.replace("Zrotation Xrotation Yrotation\n    End", "Zrot Xrotation Yrotation\n    End")) \
        .startswith("line 9: unknown channel 'Zrot'")
    assert _error(CHAIN.replace("CHANNELS 3", "CHANNELS 4")) \
        .startswith("line 9: CHANNELS says 4 channels but lists 3")
    assert _error("HIERARCH\n") == "line 1: expected 'HIERARCHY', got 'HIERARCH'"
    assert re.match(r"line 3: expected 'ROOT name'", _error("HIERARCHY\n\nJOINT x\n"))


def test_errors_from_a_file_name_the_file(tmp_path) -> None:
    path = tmp_path / "broken.bvh"
    path.write_text(_replace_line(CHAIN, 8, "OFSET 1 2"))
    with pytest.raises(BvhError, match=r"broken\.bvh: line 8: expected 'OFFSET x y z'"):
        read_bvh(path)
    assert issubclass(BvhError, ValueError)
