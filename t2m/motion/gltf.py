"""Joint positions -> an animated, skinned glTF 2.0 binary (.glb) that Blender, three.js and game engines import.

What the file holds:
- one node per joint, named like the BVH export (Hips, LeftUpLeg, ...), in a parent/child hierarchy whose node
  translations are the motion's own bone offsets (metres, Y up, glTF's units and axes) and whose rest rotations
  are identity (HumanML3D's rest pose);
- one animation "motion": a translation channel on the root and a rotation channel on every joint, one key per
  frame at time = frame / fps, LINEAR; the rotations come from `motion.ik.joints_to_rotations`;
- with body=True, a visible body: one capsule per bone (trimesh), each vertex skinned to the bone's parent joint
  with weight 1, plus spheres for the head and hands, a skin over the 22 joints with its inverse bind matrices.
  A skin (rather than meshes parented to nodes) is what importers turn into an armature with a bound mesh.

Validity details the Khronos validator checks: every buffer view starts on a 4-byte boundary, vertex attributes are
tightly packed (no byteStride needed), POSITION and animation inputs carry min/max, quaternions are unit length in
float32, key times strictly increase, the skinned mesh node is a scene root without a transform.

`glb_joint_positions` evaluates such a file (any glTF with named joint nodes and LINEAR/STEP animation) at its key
times; the tests use it to check that a file really reproduces the motion.
"""
from __future__ import annotations

import json
import struct
from collections.abc import Sequence

import numpy as np
import pygltflib
import trimesh

from t2m.motion.bvh_export import bvh_joint_names
from t2m.motion.constants import FPS
from t2m.motion.ik import joints_to_rotations
from t2m.motion.quaternion import quat_to_matrix
from t2m.motion.skeleton import SMPL22, Skeleton, get_skeleton

__all__ = ["glb_joint_positions", "joints_to_glb"]

_FLOAT = pygltflib.FLOAT
_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}
_DTYPES: dict[int, type[np.number]] = {
    pygltflib.FLOAT: np.float32, pygltflib.UNSIGNED_BYTE: np.uint8, pygltflib.UNSIGNED_SHORT: np.uint16,
    pygltflib.UNSIGNED_INT: np.uint32, pygltflib.BYTE: np.int8, pygltflib.SHORT: np.int16,
}
# Capsule radius (metres) of the bone that ends at each SMPL joint; a rough adult build, only for looks.
_BONE_RADIUS = {
    "left_hip": 0.07, "right_hip": 0.07, "spine1": 0.10, "spine2": 0.11, "spine3": 0.12, "neck": 0.055,
    "left_collar": 0.055, "right_collar": 0.055, "head": 0.05, "left_knee": 0.065, "right_knee": 0.065,
    "left_ankle": 0.05, "right_ankle": 0.05, "left_foot": 0.04, "right_foot": 0.04, "left_shoulder": 0.05,
    "right_shoulder": 0.05, "left_elbow": 0.045, "right_elbow": 0.045, "left_wrist": 0.038, "right_wrist": 0.038,
}
_DEFAULT_RADIUS = 0.04
# Spheres on leaves (joint -> radius, distance along the leaf bone's direction): head and hands.
_LEAF_SPHERES = {"head": (0.10, 0.07), "left_wrist": (0.045, 0.05), "right_wrist": (0.045, 0.05)}


class _Buffer:
    """One binary buffer assembled view by view, each view starting on a 4-byte boundary."""

    def __init__(self, gltf: pygltflib.GLTF2) -> None:
        self.gltf = gltf
        self.chunks: list[bytes] = []
        self.size = 0

    def add(self, array: np.ndarray, kind: str, component: int, target: int | None = None,
            with_bounds: bool = False, name: str | None = None) -> int:
        """Append `array` as a new buffer view + accessor; return the accessor index."""
        data = np.ascontiguousarray(array, dtype=_DTYPES[component])
        raw = data.tobytes()
        view = pygltflib.BufferView(buffer=0, byteOffset=self.size, byteLength=len(raw), target=target)
        self.gltf.bufferViews.append(view)
        padding = (-len(raw)) % 4
        self.chunks.append(raw + b"\x00" * padding)
        self.size += len(raw) + padding
        flat = data.reshape(len(data), -1)
        accessor = pygltflib.Accessor(bufferView=len(self.gltf.bufferViews) - 1, componentType=component,
                                      count=len(data), type=kind, name=name)
        if with_bounds:
            accessor.min = [float(v) for v in flat.min(axis=0)]
            accessor.max = [float(v) for v in flat.max(axis=0)]
        self.gltf.accessors.append(accessor)
        return len(self.gltf.accessors) - 1

    def blob(self) -> bytes:
        return b"".join(self.chunks)


def _body_mesh(skeleton: Skeleton, rest_world: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, ...]:
    """Vertices, normals, faces and the joint each vertex follows, in the bind (rest) pose, world space."""
    names = skeleton.joint_names
    vertices, normals, faces, owners = [], [], [], []
    count = 0

    def add(mesh: trimesh.Trimesh, owner: int) -> None:
        nonlocal count
        vertices.append(mesh.vertices)
        normals.append(mesh.vertex_normals)
        faces.append(mesh.faces + count)
        owners.append(np.full(len(mesh.vertices), owner))
        count += len(mesh.vertices)

    for joint, parent in enumerate(skeleton.parents):
        if parent < 0:
            continue
        start, end = rest_world[parent], rest_world[joint]
        length = float(np.linalg.norm(end - start))
        if length < 1e-4:
            continue
        radius = min(_BONE_RADIUS.get(names[joint], _DEFAULT_RADIUS), 0.45 * length + 0.02)
        capsule = trimesh.creation.capsule(height=length, radius=radius, count=[12, 8])
        align = trimesh.geometry.align_vectors([0.0, 0.0, 1.0], (end - start) / length)
        align[:3, 3] = 0.5 * (start + end)
        capsule.apply_transform(align)
        add(capsule, parent)
    for name, (radius, distance) in _LEAF_SPHERES.items():
        if name not in names:
            continue
        joint = names.index(name)
        direction = offsets[joint] / max(float(np.linalg.norm(offsets[joint])), 1e-9)
        sphere = trimesh.creation.icosphere(subdivisions=2, radius=radius)
        sphere.apply_translation(rest_world[joint] + distance * direction)
        add(sphere, joint)
    normals_all = np.concatenate(normals).astype(np.float32)
    normals_all /= np.linalg.norm(normals_all, axis=-1, keepdims=True)
    return (np.concatenate(vertices).astype(np.float32), normals_all,
            np.concatenate(faces).reshape(-1), np.concatenate(owners))


def joints_to_glb(joints: np.ndarray, skeleton: Skeleton | str = SMPL22, fps: float = FPS,
                  body: bool = True) -> bytes:
    """A .glb (bytes) animating `joints` [T, J, 3] (metres, Y up) at `fps`; see the module docstring."""
    skeleton = get_skeleton(skeleton)
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be a positive number, got {fps}")
    solved = joints_to_rotations(joints, skeleton)
    frames, count = solved.local_quats.shape[:2]
    parents = skeleton.parents
    names = bvh_joint_names(skeleton)

    gltf = pygltflib.GLTF2(asset=pygltflib.Asset(version="2.0", generator="t2m-service motion.gltf"))
    buffer = _Buffer(gltf)
    root_rest = solved.root_positions[0]
    for joint in range(count):
        translation = root_rest if parents[joint] < 0 else solved.offsets[joint]
        gltf.nodes.append(pygltflib.Node(
            name=names[joint], translation=[float(v) for v in translation],
            children=[c for c in range(count) if parents[c] == joint]))
    roots = [j for j in range(count) if parents[j] < 0]
    scene_nodes = list(roots)

    # bind pose: identity rotations, so each joint's rest world position is the sum of offsets down its chain
    rest_world = np.zeros((count, 3))
    for joint, parent in enumerate(parents):
        rest_world[joint] = root_rest if parent < 0 else rest_world[parent] + solved.offsets[joint]

    if body:
        vertices, normals, faces, owners = _body_mesh(skeleton, rest_world, solved.offsets)
        index_type = pygltflib.UNSIGNED_SHORT if len(vertices) < 65535 else pygltflib.UNSIGNED_INT
        attributes = pygltflib.Attributes(
            POSITION=buffer.add(vertices, "VEC3", _FLOAT, pygltflib.ARRAY_BUFFER, with_bounds=True),
            NORMAL=buffer.add(normals, "VEC3", _FLOAT, pygltflib.ARRAY_BUFFER),
            JOINTS_0=buffer.add(np.stack([owners, *[np.zeros_like(owners)] * 3], axis=-1), "VEC4",
                                pygltflib.UNSIGNED_BYTE if count < 256 else pygltflib.UNSIGNED_SHORT,
                                pygltflib.ARRAY_BUFFER),
            WEIGHTS_0=buffer.add(np.tile([1.0, 0.0, 0.0, 0.0], (len(vertices), 1)), "VEC4", _FLOAT,
                                 pygltflib.ARRAY_BUFFER),
        )
        indices = buffer.add(faces, "SCALAR", index_type, pygltflib.ELEMENT_ARRAY_BUFFER)
        gltf.materials.append(pygltflib.Material(
            name="body", pbrMetallicRoughness=pygltflib.PbrMetallicRoughness(
                baseColorFactor=[0.55, 0.62, 0.75, 1.0], metallicFactor=0.0, roughnessFactor=0.7)))
        gltf.meshes.append(pygltflib.Mesh(name="body", primitives=[pygltflib.Primitive(
            attributes=attributes, indices=indices, material=0, mode=pygltflib.TRIANGLES)]))
        inverse_bind = np.broadcast_to(np.eye(4), (count, 4, 4)).copy()
        inverse_bind[:, :3, 3] = -rest_world
        # glTF matrices are column-major: store each matrix transposed
        ibm = buffer.add(np.swapaxes(inverse_bind, 1, 2).reshape(count, 16), "MAT4", _FLOAT)
        gltf.skins.append(pygltflib.Skin(name="skeleton", joints=list(range(count)), skeleton=roots[0],
                                         inverseBindMatrices=ibm))
        gltf.nodes.append(pygltflib.Node(name="Body", mesh=0, skin=0))
        scene_nodes.append(len(gltf.nodes) - 1)

    times = buffer.add(np.arange(frames) / fps, "SCALAR", _FLOAT, with_bounds=True, name="time")
    animation = pygltflib.Animation(name="motion")
    translation_key = buffer.add(solved.root_positions, "VEC3", _FLOAT, name=f"{names[roots[0]]} translation")
    animation.samplers.append(pygltflib.AnimationSampler(input=times, output=translation_key,
                                                         interpolation=pygltflib.ANIM_LINEAR))
    animation.channels.append(pygltflib.AnimationChannel(
        sampler=0, target=pygltflib.AnimationChannelTarget(node=roots[0], path=pygltflib.TRANSLATION)))
    for joint in range(count):
        xyzw = solved.local_quats[:, joint][:, [1, 2, 3, 0]].astype(np.float32)  # glTF stores (x, y, z, w)
        xyzw /= np.linalg.norm(xyzw, axis=-1, keepdims=True)
        key = buffer.add(xyzw, "VEC4", _FLOAT, name=f"{names[joint]} rotation")
        animation.samplers.append(pygltflib.AnimationSampler(input=times, output=key,
                                                             interpolation=pygltflib.ANIM_LINEAR))
        animation.channels.append(pygltflib.AnimationChannel(
            sampler=len(animation.samplers) - 1,
            target=pygltflib.AnimationChannelTarget(node=joint, path=pygltflib.ROTATION)))
    gltf.animations.append(animation)

    gltf.scenes.append(pygltflib.Scene(name="motion", nodes=scene_nodes))
    gltf.scene = 0
    blob = buffer.blob()
    gltf.buffers.append(pygltflib.Buffer(byteLength=len(blob)))
    gltf.set_binary_blob(blob)
    return b"".join(gltf.save_to_bytes())


# --- reading back -----------------------------------------------------------------------------------------------
def _parse_glb(glb: bytes) -> tuple[dict, bytes]:
    """The JSON document and the BIN chunk of a .glb (read with struct/json: independent of the writer library)."""
    if len(glb) < 20:
        raise ValueError("not a glb file: shorter than a glb header")
    magic, version, length = struct.unpack_from("<4sII", glb, 0)
    if magic != b"glTF" or version != 2 or length > len(glb):
        raise ValueError(f"not a glb 2.0 file (magic {magic!r}, version {version}, length {length})")
    offset, document, binary = 12, None, b""
    while offset + 8 <= length:
        chunk_length, chunk_type = struct.unpack_from("<I4s", glb, offset)
        data = glb[offset + 8 : offset + 8 + chunk_length]
        if chunk_type == b"JSON":
            document = json.loads(data.decode("utf-8"))
        elif chunk_type == b"BIN\x00":
            binary = data
        offset += 8 + chunk_length
    if document is None:
        raise ValueError("not a glb file: no JSON chunk")
    return document, binary


def _read_accessor(document: dict, blob: bytes, index: int) -> np.ndarray:
    accessor = document["accessors"][index]
    view = document["bufferViews"][accessor["bufferView"]]
    scalar = _DTYPES[accessor["componentType"]]
    dtype = np.dtype(scalar)
    width = _COMPONENTS[accessor["type"]]
    count = accessor["count"]
    stride = view.get("byteStride") or dtype.itemsize * width
    start = view.get("byteOffset", 0) + accessor.get("byteOffset", 0)
    if count == 0:
        return np.zeros((0, width))
    span = (count - 1) * stride + dtype.itemsize * width
    raw = np.frombuffer(blob, dtype=np.uint8, count=span, offset=start)
    rows = np.lib.stride_tricks.as_strided(raw, shape=(count, dtype.itemsize * width), strides=(stride, 1))
    values = np.ascontiguousarray(rows).view(dtype).reshape(count, width).astype(np.float64)
    if accessor.get("normalized") and issubclass(scalar, np.integer):
        values /= np.iinfo(scalar).max
    return values


def _sample(times: np.ndarray, keys: np.ndarray, at: np.ndarray, rotation: bool, step: bool) -> np.ndarray:
    """Values of a LINEAR (or STEP) sampler at times `at`; rotations by slerp along the shorter arc."""
    at = np.clip(at, times[0], times[-1])
    if len(times) == 1:
        return np.repeat(keys[:1], len(at), axis=0)
    upper = np.clip(np.searchsorted(times, at, side="right"), 1, len(times) - 1)
    lower = upper - 1
    u = np.clip((at - times[lower]) / (times[upper] - times[lower]), 0.0, 1.0)[:, None]
    if step:
        u = np.where(u >= 1.0, 1.0, 0.0)
    a, b = keys[lower], keys[upper]
    if not rotation:
        return (1 - u) * a + u * b
    b = np.where(np.sum(a * b, -1, keepdims=True) < 0, -b, b)
    angle = np.arccos(np.clip(np.sum(a * b, -1, keepdims=True), -1.0, 1.0))
    sin = np.sin(angle)
    safe = sin > 1e-6
    wa = np.where(safe, np.sin((1 - u) * angle) / np.where(safe, sin, 1.0), 1 - u)
    wb = np.where(safe, np.sin(u * angle) / np.where(safe, sin, 1.0), u)
    out = wa * a + wb * b
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def glb_joint_positions(glb: bytes, joint_names: Sequence[str] | None = None,
                        times: np.ndarray | None = None) -> np.ndarray:
    """World positions [T, J, 3] of the named joint nodes of a .glb, animated by its first animation.

    `joint_names` defaults to the SMPL-22 BVH names; `times` defaults to the animation's key times (one per frame
    for our files). Raises ValueError if the file is not a glb, has no animation or lacks a named joint.
    """
    document, blob = _parse_glb(glb)
    nodes = document.get("nodes", [])
    animations = document.get("animations", [])
    if not animations:
        raise ValueError("glb has no animation")
    joint_names = list(joint_names) if joint_names is not None else bvh_joint_names(SMPL22)
    by_name = {node.get("name"): i for i, node in enumerate(nodes)}
    missing = [name for name in joint_names if name not in by_name]
    if missing:
        raise ValueError(f"glb has no node named {', '.join(missing)}")
    animation = animations[0]
    if times is None:
        first = animation["samplers"][animation["channels"][0]["sampler"]]
        times = _read_accessor(document, blob, first["input"])[:, 0]
    times = np.asarray(times, dtype=np.float64).reshape(-1)
    frames, count = len(times), len(nodes)

    translation = np.zeros((frames, count, 3))
    rotation = np.zeros((frames, count, 4))
    rotation[..., 3] = 1.0
    scale = np.ones((frames, count, 3))
    for index, node in enumerate(nodes):
        translation[:, index] = node.get("translation", [0.0, 0.0, 0.0])
        rotation[:, index] = node.get("rotation", [0.0, 0.0, 0.0, 1.0])
        scale[:, index] = node.get("scale", [1.0, 1.0, 1.0])
    for channel in animation["channels"]:
        target = channel["target"]
        path, node = target["path"], target.get("node")
        if node is None or path not in ("translation", "rotation", "scale"):
            continue
        sampler = animation["samplers"][channel["sampler"]]
        keys_time = _read_accessor(document, blob, sampler["input"])[:, 0]
        keys = _read_accessor(document, blob, sampler["output"])
        values = _sample(keys_time, keys, times, rotation=path == "rotation",
                         step=sampler.get("interpolation", "LINEAR") == "STEP")
        {"translation": translation, "rotation": rotation, "scale": scale}[path][:, node] = values

    local = np.broadcast_to(np.eye(4), (frames, count, 4, 4)).copy()
    local[..., :3, :3] = quat_to_matrix(rotation[..., [3, 0, 1, 2]]) * scale[..., None, :]  # glTF is (x, y, z, w)
    local[..., :3, 3] = translation
    for index, node in enumerate(nodes):
        if "matrix" in node:  # a node with a matrix is not animated (glTF rule); matrices are column-major
            local[:, index] = np.array(node["matrix"], dtype=np.float64).reshape(4, 4).T
    parent_of = {child: index for index, node in enumerate(nodes) for child in node.get("children", [])}
    world: dict[int, np.ndarray] = {}

    def resolve(index: int) -> np.ndarray:
        if index not in world:
            parent = parent_of.get(index)
            world[index] = local[:, index] if parent is None else resolve(parent) @ local[:, index]
        return world[index]

    return np.stack([resolve(by_name[name])[:, :3, 3] for name in joint_names], axis=1)
