"""Joint positions -> joint rotations (inverse kinematics) for the BVH and glTF exports (numpy only).

A generated motion is 22 positions per frame; BVH, glTF and every animation tool want a rigid skeleton with one
rotation per joint. The solver here is analytic, one pass per joint in parent-before-child order, vectorised over
frames, and uses no world axis anywhere, so it behaves the same whatever the heading (the field's exporters break
when the character faces backwards) and stays finite on any input (upside down, collapsed bones, random points).

How each joint's world rotation G_j is chosen (the positions only fix the swing; the twist is a choice):
- several children (SMPL: pelvis, spine3): the best-fit rotation (Kabsch/SVD) of the rest child offsets onto the
  child vectors. The children's rest offsets are fitted from the motion itself (their mean shape in the joint's
  frame), because in HumanML3D data the hips sit below the pelvis (about 143 degrees between hip and spine, not
  the 90 of the skeleton's rest directions): with the skeleton's directions the pelvis could not reproduce them;
- one child, limb (hips, knees, shoulders, elbows): the rest bone is aimed exactly at the child and the twist puts
  the joint's hinge axis on the normal of the limb's bend plane (hip-knee-ankle, shoulder-elbow-wrist), so knees and
  elbows bend about their own axis; when the limb is nearly straight the twist falls back to the parent's;
- one child, spine1/spine2: aimed at the child, twist from the hips line blended with the shoulders line (2:1, 1:2),
  so a torso twist is spread over the spine rather than lumped into one joint;
- one child, anything else (neck, collars, ankles): the minimal rotation (swing only) from the parent's frame;
- no child (head, wrists, toes): identity local rotation, i.e. the parent's twist. Positions carry no information
  about a hand's or the head's roll, so this is the only honest choice; it is also what the field's exporters do.
Each bone is aimed from the *reconstructed* parent position, so a motion whose bone lengths wobble (generated
motion) gets an error of the length wobble only, never accumulated down a chain.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from t2m.motion.quaternion import matrix_to_quat, qbetween, quat_to_matrix
from t2m.motion.skeleton import SMPL22, Skeleton, get_skeleton

__all__ = ["IKResult", "joints_to_rotations", "motion_offsets", "rotations_to_joints"]

_TINY = 1e-9
# Below this sine of the bend angle a limb counts as straight and its twist falls back to the parent's.
_STRAIGHT_SINE = 0.2
# Limb hinges: (upper, middle, lower joint, direction the lower bone swings to when the limb bends, in the rest frame).
# Knees bend backwards (the shin goes to -z, the body faces +z); elbows bend forwards.
_LIMBS = (
    ("left_hip", "left_knee", "left_ankle", (0.0, 0.0, -1.0)),
    ("right_hip", "right_knee", "right_ankle", (0.0, 0.0, -1.0)),
    ("left_shoulder", "left_elbow", "left_wrist", (0.0, 0.0, 1.0)),
    ("right_shoulder", "right_elbow", "right_wrist", (0.0, 0.0, 1.0)),
)
# Spine joints whose twist blends the hips line (weight w) with the shoulders line (weight 1 - w).
_SPINE_TWIST = (("spine1", 2.0 / 3.0), ("spine2", 1.0 / 3.0))


class IKResult(NamedTuple):
    """Root positions [T, 3], local rotations [T, J, 4] (w, x, y, z; sign-continuous in time) and the bone offsets
    [J, 3] (metres, rest frame) they were solved for: FK with these three gives the joints back."""

    root_positions: np.ndarray
    local_quats: np.ndarray
    offsets: np.ndarray


def _unit(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors and their original lengths; zero vectors stay zero (callers substitute a fallback)."""
    length = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.maximum(length, _TINY), length[..., 0]


def _children(parents: tuple[int, ...] | np.ndarray) -> list[list[int]]:
    children: list[list[int]] = [[] for _ in parents]
    for joint, parent in enumerate(parents):
        if parent >= 0:
            children[parent].append(joint)
    return children


def _check_joints(joints: np.ndarray, skeleton: Skeleton) -> np.ndarray:
    joints = np.asarray(joints, dtype=np.float64)
    if joints.ndim != 3 or joints.shape[1:] != (skeleton.num_joints, 3) or joints.shape[0] < 1:
        raise ValueError(f"joints must have shape [frames >= 1, {skeleton.num_joints}, 3] for skeleton "
                         f"{skeleton.name}, got {list(joints.shape)}")
    if not np.all(np.isfinite(joints)):
        frame = int(np.argwhere(~np.isfinite(joints))[0, 0])
        raise ValueError(f"joints: frame {frame} has a non-finite coordinate")
    if any(parent >= joint for joint, parent in enumerate(skeleton.parents)):
        raise ValueError(f"skeleton {skeleton.name}: every parent must come before its children")
    return joints


def _kabsch(rest: np.ndarray, target: np.ndarray, prior: np.ndarray) -> np.ndarray:
    """Rotations [T, 3, 3] best taking the rest vectors [K, 3] onto the target vectors [T, K, 3].

    A vanishing pull towards `prior` [T, 3, 3] decides the cases the children leave open (collinear or collapsed
    children) instead of letting the SVD pick an arbitrary twist; it moves a well-posed answer by ~1e-9 rad.
    """
    m = np.einsum("ki,tkj->tij", rest, target)
    scale = np.linalg.norm(rest, axis=-1).sum() * np.linalg.norm(target, axis=-1).sum(-1)
    m = m + (1e-9 * scale + _TINY)[:, None, None] * np.swapaxes(prior, -1, -2)
    u, _, vt = np.linalg.svd(m)
    v = np.swapaxes(vt, -1, -2)
    ut = np.swapaxes(u, -1, -2)
    d = np.sign(np.linalg.det(v @ ut))
    d = np.where(d == 0, 1.0, d)
    fix = np.broadcast_to(np.eye(3), m.shape).copy()
    fix[:, 2, 2] = d
    return v @ fix @ ut


def _swing(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Minimal rotation matrices [T, 3, 3] taking unit vectors a onto unit vectors b (both [T, 3] or [3])."""
    return quat_to_matrix(qbetween(a, b))


def _frame_align(d: np.ndarray, h: np.ndarray, v: np.ndarray, s: np.ndarray,
                 fallback: np.ndarray) -> np.ndarray:
    """Rotations taking rest direction d onto v exactly and the rest secondary h as close to s as that allows.

    d, h are [3] (rest frame, h not parallel to d); v, s are [T, 3]; where s is (nearly) parallel to v the twist is
    undefined and `fallback` [T, 3, 3] is used.
    """
    h_perp, _ = _unit(h - (h @ d) * d)
    rest = np.stack([d, h_perp, np.cross(d, h_perp)], axis=-1)
    s_perp, s_len = _unit(s - np.sum(s * v, -1, keepdims=True) * v)
    target = np.stack([v, s_perp, np.cross(v, s_perp)], axis=-1)
    aligned = target @ rest.T
    return np.where((s_len > 1e-6)[:, None, None], aligned, fallback)


def _bone_lengths(joints: np.ndarray, parents: tuple[int, ...]) -> np.ndarray:
    lengths = np.zeros(len(parents))
    for joint, parent in enumerate(parents):
        if parent >= 0:
            lengths[joint] = np.linalg.norm(joints[:, joint] - joints[:, parent], axis=-1).mean()
    return lengths


def motion_offsets(joints: np.ndarray, skeleton: Skeleton | str = SMPL22) -> np.ndarray:
    """The rigid skeleton [J, 3] (metres, rest frame) that best fits this motion.

    Every bone keeps the motion's own mean length. A bone whose parent has one child keeps the skeleton's rest
    direction (the solver aims it exactly). The children of a joint with several children keep the motion's own
    shape: their mean vectors in that joint's frame, the frame being the best fit of the skeleton's rest
    directions - so the fitted rest pose stays as close to the skeleton's as the data allows.
    """
    skeleton = get_skeleton(skeleton)
    joints = _check_joints(joints, skeleton)
    parents = skeleton.parents
    lengths = _bone_lengths(joints, parents)
    directions = skeleton.rest_directions
    offsets = directions * lengths[:, None]
    frames = len(joints)
    for joint, kids in enumerate(_children(parents)):
        if len(kids) < 2:
            continue
        vectors = joints[:, kids] - joints[:, joint : joint + 1]
        frame = _kabsch(offsets[kids], vectors, np.broadcast_to(np.eye(3), (frames, 3, 3)))
        local = np.einsum("tji,tkj->tki", frame, vectors).mean(axis=0)  # frame^T @ vector, averaged over time
        unit, norm = _unit(local)
        offsets[kids] = np.where(norm[:, None] > _TINY, unit, directions[kids]) * lengths[kids, None]
    return offsets


def _limb_hinges(skeleton: Skeleton) -> dict[int, tuple[int, int, int, np.ndarray]]:
    """joint -> (upper, middle, lower, rest hinge axis) for the hip/knee/shoulder/elbow joints of this skeleton."""
    names = skeleton.joint_names
    hinges: dict[int, tuple[int, int, int, np.ndarray]] = {}
    for upper, middle, lower, bend in _LIMBS:
        if not {upper, middle, lower} <= set(names):
            continue
        a, b, c = (names.index(n) for n in (upper, middle, lower))
        if skeleton.parents[b] != a or skeleton.parents[c] != b:
            continue
        axis, norm = _unit(np.cross(skeleton.rest_directions[b], np.asarray(bend)))
        if norm < 1e-6:
            continue
        hinges[a] = hinges[b] = (a, b, c, axis)
    return hinges


def joints_to_rotations(joints: np.ndarray, skeleton: Skeleton | str = SMPL22) -> IKResult:
    """Solve root positions and local joint rotations whose FK (with `IKResult.offsets`) reproduces `joints`.

    joints: [T, J, 3] world positions in metres (any heading, any pose). The error of the reproduction is zero for a
    rigid motion (HumanML3D data: < 1e-6 m) and the bone-length wobble otherwise. See the module docstring for how
    twists are chosen.
    """
    skeleton = get_skeleton(skeleton)
    joints = _check_joints(joints, skeleton)
    parents = skeleton.parents
    children = _children(parents)
    offsets = motion_offsets(joints, skeleton)
    lengths = np.linalg.norm(offsets, axis=-1)
    directions = skeleton.rest_directions
    hinges = _limb_hinges(skeleton)
    names = skeleton.joint_names
    spine_twist = {names.index(n): w for n, w in _SPINE_TWIST if n in names}
    r_hip, l_hip, r_shoulder, l_shoulder = skeleton.face_joints
    hips_line, _ = _unit(joints[:, l_hip] - joints[:, r_hip])
    shoulders_line, _ = _unit(joints[:, l_shoulder] - joints[:, r_shoulder])
    rest_across, _ = _unit(offsets[l_hip] - offsets[r_hip])

    frames, count = joints.shape[:2]
    identity = np.broadcast_to(np.eye(3), (frames, 3, 3))
    world = np.empty((frames, count, 3, 3))
    placed = np.empty((frames, count, 3))  # reconstructed positions
    for joint in range(count):
        parent = parents[joint]
        parent_world = identity if parent < 0 else world[:, parent]
        if parent < 0:
            placed[:, joint] = joints[:, joint]
        kids = children[joint]
        if not kids:
            world[:, joint] = parent_world
            continue
        if len(kids) > 1:
            vectors = joints[:, kids] - placed[:, joint : joint + 1]
            world[:, joint] = _kabsch(offsets[kids], vectors, parent_world)
        else:
            child = kids[0]
            d = directions[child] if lengths[child] > _TINY else np.array([0.0, 1.0, 0.0])
            rest_now = parent_world @ d
            v, v_len = _unit(joints[:, child] - placed[:, joint])
            v = np.where((v_len > _TINY)[:, None], v, rest_now)  # a collapsed bone keeps the parent's direction
            swing = _swing(rest_now, v) @ parent_world
            if joint in hinges:
                upper, middle, lower, axis = hinges[joint]
                bent = np.cross(_unit(joints[:, middle] - joints[:, upper])[0],
                                _unit(joints[:, lower] - joints[:, middle])[0])
                bent_unit, sine = _unit(bent)
                weight = np.clip(sine / _STRAIGHT_SINE, 0.0, 1.0)[:, None]
                fallback_axis = (parent_world if joint == upper else world[:, upper]) @ axis
                secondary = weight * bent_unit + (1.0 - weight) * fallback_axis
                world[:, joint] = _frame_align(d, axis, v, secondary, swing)
            elif joint in spine_twist and np.linalg.norm(np.cross(d, rest_across)) > 1e-6:
                w = spine_twist[joint]
                world[:, joint] = _frame_align(d, rest_across, v, w * hips_line + (1 - w) * shoulders_line, swing)
            else:
                world[:, joint] = swing
        for kid in kids:
            placed[:, kid] = placed[:, joint] + world[:, joint] @ offsets[kid]

    local = np.empty_like(world)
    local[:, 0] = world[:, 0]
    for joint in range(1, count):
        local[:, joint] = np.swapaxes(world[:, parents[joint]], -1, -2) @ world[:, joint]
    quats = _continuous(matrix_to_quat(local))
    return IKResult(root_positions=joints[:, 0].copy(), local_quats=quats, offsets=offsets)


def _continuous(quats: np.ndarray) -> np.ndarray:
    """Flip signs so consecutive quaternions of a joint lie in the same hemisphere (clean interpolation)."""
    quats = quats.copy()
    for frame in range(1, len(quats)):
        flip = np.sum(quats[frame] * quats[frame - 1], axis=-1) < 0
        quats[frame, flip] *= -1.0
    return quats


def rotations_to_joints(root_positions: np.ndarray, local_quats: np.ndarray, offsets: np.ndarray,
                        parents: tuple[int, ...] | np.ndarray) -> np.ndarray:
    """Forward kinematics: world positions [T, J, 3] from root positions, local rotations and bone offsets."""
    local = quat_to_matrix(np.asarray(local_quats, dtype=np.float64))
    frames, count = local.shape[:2]
    world = np.empty_like(local)
    positions = np.empty((frames, count, 3))
    for joint, parent in enumerate(parents):
        if parent < 0:
            world[:, joint] = local[:, joint]
            positions[:, joint] = root_positions
        else:
            world[:, joint] = world[:, parent] @ local[:, joint]
            positions[:, joint] = positions[:, parent] + world[:, parent] @ offsets[joint]
    return positions
