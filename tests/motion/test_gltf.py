"""motion.gltf: a valid, skinned, animated glb whose joint nodes reproduce the motion."""
from __future__ import annotations

import numpy as np
import pygltflib
import pytest

from t2m.motion.bvh_export import bvh_joint_names
from t2m.motion.gltf import glb_joint_positions, joints_to_glb
from t2m.motion.quaternion import quat_to_matrix
from t2m.motion.transforms import mirror_joints

NAMES = bvh_joint_names()


def yaw(joints: np.ndarray, degrees: float) -> np.ndarray:
    a = np.radians(degrees)
    rotation = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    return joints @ rotation.T


@pytest.fixture(scope="module")
def sample(humanml3d_sample) -> np.ndarray:
    return humanml3d_sample["joints"].astype(np.float64)


@pytest.fixture(scope="module")
def glb(sample) -> bytes:
    return joints_to_glb(sample, fps=20)


def accessor(gltf: pygltflib.GLTF2, index: int) -> np.ndarray:
    a = gltf.accessors[index]
    view = gltf.bufferViews[a.bufferView]
    dtype = {pygltflib.FLOAT: np.float32, pygltflib.UNSIGNED_BYTE: np.uint8,
             pygltflib.UNSIGNED_SHORT: np.uint16, pygltflib.UNSIGNED_INT: np.uint32}[a.componentType]
    width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}[a.type]
    assert view.byteStride in (None, 0), "we write tightly packed views"
    return np.frombuffer(gltf.binary_blob(), dtype=dtype, count=a.count * width,
                         offset=view.byteOffset + (a.byteOffset or 0)).reshape(a.count, width)


@pytest.mark.parametrize("mirrored", [False, True])
@pytest.mark.parametrize("heading", [0, 90, 180, 270])
def test_animated_joint_nodes_reproduce_the_motion(sample, heading, mirrored):
    joints = yaw(mirror_joints(sample) if mirrored else sample, heading)
    positions = glb_joint_positions(joints_to_glb(joints, body=False))
    error = np.linalg.norm(positions - joints, axis=-1)
    assert error.max() < 1e-3, f"max error {error.max():.2e} m"
    assert error.mean() < 1e-5


def test_structure_follows_gltf_rules(glb, sample):
    gltf = pygltflib.GLTF2.load_from_bytes(glb)
    assert gltf.asset.version == "2.0"
    assert [n.name for n in gltf.nodes[:22]] == NAMES
    assert gltf.scenes[gltf.scene].nodes == [0, 22] and gltf.nodes[22].skin == 0 and gltf.nodes[22].mesh == 0
    # buffer views start on 4-byte boundaries and fit in the one buffer
    blob = gltf.binary_blob()
    assert gltf.buffers[0].byteLength == len(blob)
    for view in gltf.bufferViews:
        assert view.byteOffset % 4 == 0 and view.byteOffset + view.byteLength <= len(blob)
    (animation,) = gltf.animations
    assert len(animation.channels) == 23  # root translation + 22 rotations
    times = accessor(gltf, animation.samplers[0].input)[:, 0]
    np.testing.assert_allclose(times, np.arange(len(sample)) / 20.0, atol=1e-6)
    assert np.all(np.diff(times) > 0)
    assert gltf.accessors[animation.samplers[0].input].min == [0.0]
    for sampler, channel in zip(animation.samplers, animation.channels):
        assert sampler.interpolation == "LINEAR" and sampler.input == animation.samplers[0].input
        if channel.target.path == "rotation":
            np.testing.assert_allclose(np.linalg.norm(accessor(gltf, sampler.output), axis=-1), 1.0, atol=1e-6)
    position = gltf.accessors[gltf.meshes[0].primitives[0].attributes.POSITION]
    values = accessor(gltf, gltf.meshes[0].primitives[0].attributes.POSITION)
    np.testing.assert_allclose(position.min, values.min(0)) and np.testing.assert_allclose(position.max, values.max(0))


def test_skinned_body_follows_the_bones(glb, sample):
    """Skin the capsules with the file's own inverse bind matrices at an animated frame: every vertex of the left
    thigh's capsule must lie within its radius of the animated hip-knee segment."""
    gltf = pygltflib.GLTF2.load_from_bytes(glb)
    primitive = gltf.meshes[0].primitives[0]
    vertices = accessor(gltf, primitive.attributes.POSITION).astype(np.float64)
    owners = accessor(gltf, primitive.attributes.JOINTS_0)
    weights = accessor(gltf, primitive.attributes.WEIGHTS_0)
    np.testing.assert_allclose(weights.sum(-1), 1.0)
    inverse_bind = accessor(gltf, gltf.skins[0].inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
    assert len(gltf.skins[0].joints) == 22

    frame = 100
    # world matrices of the joints at that frame, from the file's animation (rotation keys + hierarchy)
    animation = gltf.animations[0]
    world = np.zeros((22, 4, 4))
    for joint in range(22):
        node = gltf.nodes[joint]
        local = np.eye(4)
        local[:3, 3] = node.translation
        for sampler, channel in zip(animation.samplers, animation.channels):
            if channel.target.node == joint:
                value = accessor(gltf, sampler.output)[frame].astype(np.float64)
                if channel.target.path == "rotation":
                    local[:3, :3] = quat_to_matrix(value[[3, 0, 1, 2]])
                else:
                    local[:3, 3] = value
        parent = next((p for p in range(22) if joint in (gltf.nodes[p].children or [])), None)
        world[joint] = local if parent is None else world[parent] @ local
    np.testing.assert_allclose(world[:, :3, 3], sample[frame], atol=1e-5)

    skinned = np.einsum("vij,vj->vi", world[owners[:, 0]] @ inverse_bind[owners[:, 0]],
                        np.concatenate([vertices, np.ones((len(vertices), 1))], axis=1))[:, :3]
    hip, knee = sample[frame, 1], sample[frame, 4]
    thigh = owners[:, 0] == 1
    axis = (knee - hip) / np.linalg.norm(knee - hip)
    along = np.clip((skinned[thigh] - hip) @ axis, 0, np.linalg.norm(knee - hip))
    distance = np.linalg.norm(skinned[thigh] - (hip + along[:, None] * axis), axis=-1)
    assert thigh.sum() > 50 and distance.max() < 0.066  # thigh capsule radius 0.065 m


def test_body_is_optional(sample):
    gltf = pygltflib.GLTF2.load_from_bytes(joints_to_glb(sample[:5], body=False))
    assert not gltf.meshes and not gltf.skins and len(gltf.nodes) == 22


def test_single_frame_and_fps(sample):
    one = joints_to_glb(sample[:1])
    np.testing.assert_allclose(glb_joint_positions(one), sample[:1], atol=1e-5)
    gltf = pygltflib.GLTF2.load_from_bytes(joints_to_glb(sample[:4], fps=30, body=False))
    times = accessor(gltf, gltf.animations[0].samplers[0].input)[:, 0]
    np.testing.assert_allclose(times, np.arange(4) / 30, atol=1e-7)


def test_evaluator_interpolates_between_keys(sample):
    """Between two keys the evaluator slerps: at t = 0.5 frame the joints lie between the two frames' poses."""
    glb = joints_to_glb(sample[:2], body=False)
    middle = glb_joint_positions(glb, times=np.array([0.025]))[0]
    assert np.linalg.norm(middle - 0.5 * (sample[0] + sample[1]), axis=-1).max() < 0.01


def test_bad_input_is_a_value_error(sample):
    with pytest.raises(ValueError, match="fps"):
        joints_to_glb(sample, fps=-1)
    with pytest.raises(ValueError, match="joints must have shape"):
        joints_to_glb(sample[:, :5])
    with pytest.raises(ValueError, match="glb"):
        glb_joint_positions(b"not a glb")
