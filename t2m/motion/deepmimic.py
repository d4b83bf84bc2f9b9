"""DeepMimic motion files (`{"Loop", "Frames"}`) and their characters, read into joint positions by forward kinematics.

A DeepMimic frame is [duration, root position (3), root rotation (w, x, y, z), then per joint its degrees of
freedom in the character's joint order]: a quaternion (w, x, y, z) for a `spherical` joint, one angle in radians
about the joint's local z axis for a `revolute` one (knees, elbows), nothing for `fixed` (wrists) or the root.
Positions are in metres, y up; the character faces +x in its rest frame and its right side is +z. Every joint sits at
its parent plus the parent's world rotation applied to the joint's `Attach` offset (DeepMimic's attach angles are
zero in the characters read here; a character with others is refused).
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from t2m.motion.quaternion import qfrom_axis_angle, qmul, qnormalize, qrot

__all__ = ["HUMANOID3D", "DeepMimicCharacter", "DeepMimicMotion", "read_character", "read_deepmimic"]

_DOFS = {"none": 0, "spherical": 4, "revolute": 1, "fixed": 0}
_Z_AXIS = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class DeepMimicCharacter:
    """A DeepMimic skeleton: joint names, types (none/spherical/revolute/fixed), parents and attach offsets [J, 3]."""

    names: tuple[str, ...]
    types: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: np.ndarray

    @property
    def frame_size(self) -> int:
        """Numbers per frame: duration + root position + root quaternion + every joint's degrees of freedom."""
        return 1 + 3 + 4 + sum(_DOFS[t] for t in self.types[1:])

    def index(self, name: str) -> int:
        return self.names.index(name)


# deepmimic/characters/humanoid3d.txt (DeepMimic's humanoid, about 1.6 m), the character of the CMU conversions.
HUMANOID3D = DeepMimicCharacter(
    names=("root", "chest", "neck", "right_hip", "right_knee", "right_ankle", "right_shoulder", "right_elbow",
           "right_wrist", "left_hip", "left_knee", "left_ankle", "left_shoulder", "left_elbow", "left_wrist"),
    types=("none", "spherical", "spherical", "spherical", "revolute", "spherical", "spherical", "revolute", "fixed",
           "spherical", "revolute", "spherical", "spherical", "revolute", "fixed"),
    parents=(-1, 0, 1, 0, 3, 4, 1, 6, 7, 0, 9, 10, 1, 12, 13),
    offsets=np.array([
        [0.0, 0.0, 0.0], [0.0, 0.236151, 0.0], [0.0, 0.223894, 0.0], [0.0, 0.0, 0.084887],
        [0.0, -0.421546, 0.0], [0.0, -0.40987, 0.0], [-0.02405, 0.2435, 0.18311], [0.0, -0.274788, 0.0],
        [0.0, -0.258947, 0.0], [0.0, 0.0, -0.084887], [0.0, -0.421546, 0.0], [0.0, -0.40987, 0.0],
        [-0.02405, 0.2435, -0.18311], [0.0, -0.274788, 0.0], [0.0, -0.258947, 0.0],
    ]),
)


def read_character(path: str | os.PathLike) -> DeepMimicCharacter:
    """A DeepMimic character file (`{"Skeleton": {"Joints": [...]}}`), joints in file order (their IDs)."""
    try:
        joints = json.loads(Path(path).read_text(encoding="utf-8"))["Skeleton"]["Joints"]
        names = tuple(str(j["Name"]) for j in joints)
        types = tuple(str(j["Type"]) for j in joints)
        parents = tuple(int(j["Parent"]) for j in joints)
        offsets = np.array([[float(j["AttachX"]), float(j["AttachY"]), float(j["AttachZ"])] for j in joints])
        angles = [float(j.get(f"AttachTheta{a}", 0.0)) for j in joints for a in "XYZ"]
        ids = [int(j["ID"]) for j in joints]
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise ValueError(f"{path}: expected a DeepMimic character ({{\"Skeleton\": {{\"Joints\": [...]}}}}): "
                         f"{error}") from None
    if ids != list(range(len(ids))) or any(t not in _DOFS for t in types) or any(p >= i for i, p in enumerate(parents)):
        raise ValueError(f"{path}: expected joints listed by ID, parents first, types in {sorted(_DOFS)}")
    if any(abs(a) > 1e-9 for a in angles):
        raise ValueError(f"{path}: joints with non-zero AttachTheta angles are not supported")
    return DeepMimicCharacter(names, types, parents, offsets)


@dataclass(frozen=True)
class DeepMimicMotion:
    """World joint positions [T, J, 3] (metres, y up) and rotations [T, J, 4] of a DeepMimic clip, at `fps`."""

    character: DeepMimicCharacter
    positions: np.ndarray
    rotations: np.ndarray
    fps: float

    @property
    def num_frames(self) -> int:
        return len(self.positions)


def _frames(path: str | os.PathLike, character: DeepMimicCharacter) -> tuple[np.ndarray, float]:
    """The frame matrix [T, frame_size] and the frame rate (every frame but the last lasts the same)."""
    try:
        document = json.loads(Path(path).read_text(encoding="utf-8"))
        frames = np.asarray(document["Frames"], dtype=np.float64)
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise ValueError(f"{path}: expected DeepMimic JSON {{\"Loop\", \"Frames\": [[...], ...]}}: {error}") from None
    if frames.ndim != 2 or frames.shape[1] != character.frame_size or len(frames) < 2:
        raise ValueError(f"{path}: expected at least 2 frames of {character.frame_size} numbers "
                         f"(the {len(character.names)}-joint character), got shape {frames.shape}")
    if not np.isfinite(frames).all():
        raise ValueError(f"{path}: frames hold non-finite numbers")
    durations = frames[:-1, 0]
    if durations.min() <= 0 or np.ptp(durations) > 1e-6:
        raise ValueError(f"{path}: expected every frame (but the last) to last the same positive time, got "
                         f"{durations.min():.6f}..{durations.max():.6f} s")
    return frames, float(1.0 / durations.mean())


def read_deepmimic(path: str | os.PathLike, character: DeepMimicCharacter = HUMANOID3D) -> DeepMimicMotion:
    """Read a DeepMimic motion file and run forward kinematics over `character`."""
    frames, fps = _frames(path, character)
    count, joints = len(frames), len(character.names)
    local = np.zeros((count, joints, 4))
    local[..., 0] = 1.0
    local[:, 0] = qnormalize(frames[:, 4:8])
    column = 8
    for j, kind in enumerate(character.types[1:], start=1):
        if kind == "spherical":
            local[:, j] = qnormalize(frames[:, column:column + 4])
        elif kind == "revolute":
            local[:, j] = qfrom_axis_angle(np.broadcast_to(_Z_AXIS, (count, 3)), frames[:, column])
        column += _DOFS[kind]
    rotations = np.zeros_like(local)
    positions = np.zeros((count, joints, 3))
    rotations[:, 0], positions[:, 0] = local[:, 0], frames[:, 1:4]
    for j in range(1, joints):
        parent = character.parents[j]
        rotations[:, j] = qmul(rotations[:, parent], local[:, j])
        positions[:, j] = positions[:, parent] + qrot(rotations[:, parent],
                                                      np.broadcast_to(character.offsets[j], (count, 3)))
    return DeepMimicMotion(character, positions, rotations, fps)
