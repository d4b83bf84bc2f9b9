"""The two skeletons of the HumanML3D family: SMPL-22 (HumanML3D, 263-dim features) and KIT-21 (KIT-ML, 251-dim).

A skeleton is data, not behaviour: joint order, parents, rest offsets and the joint roles the feature extraction
needs (feet for contacts, hips/shoulders for the facing direction). Everything else reads these tables.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class Skeleton:
    """A kinematic tree with HumanML3D's rest pose.

    offsets[j] is the rest vector from parent(j) to j in metres: a unit rest direction (HumanML3D's "raw offsets")
    times the reference bone length. kinematic_chain lists the chains HumanML3D's IK and FK walk (each starts at an
    already-placed joint). foot_joints = (l_heel, l_toe, r_heel, r_toe) in the order of the contact channels;
    face_joints = (r_hip, l_hip, r_shoulder, l_shoulder) for the facing direction.
    feet_threshold is HumanML3D's contact threshold on squared per-frame displacement, in `units_per_metre` units
    (the units the dataset's joint files use: metres for HumanML3D, millimetres for KIT-ML).
    """

    name: str
    joint_names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: np.ndarray
    kinematic_chain: tuple[tuple[int, ...], ...]
    left_right_pairs: tuple[tuple[int, int], ...]
    foot_joints: tuple[int, int, int, int]
    face_joints: tuple[int, int, int, int]
    feet_threshold: float = 0.002
    units_per_metre: float = 1.0

    def __post_init__(self) -> None:
        offsets = np.array(self.offsets, dtype=np.float64)
        offsets.setflags(write=False)
        object.__setattr__(self, "offsets", offsets)
        if offsets.shape != (self.num_joints, 3) or len(self.parents) != self.num_joints:
            raise ValueError(f"skeleton {self.name}: offsets/parents do not match {self.num_joints} joint names")

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)

    @property
    def bone_lengths(self) -> np.ndarray:
        """Reference length of the bone ending at each joint (0 for the root), metres."""
        return np.linalg.norm(self.offsets, axis=-1)

    @property
    def rest_directions(self) -> np.ndarray:
        """Unit rest direction of each bone (zero for the root): HumanML3D's raw offsets."""
        lengths = self.bone_lengths
        return np.divide(self.offsets, lengths[:, None], out=np.zeros_like(self.offsets), where=lengths[:, None] > 0)

    @property
    def mirror_permutation(self) -> np.ndarray:
        """Index array that swaps every left/right pair (joint j of the mirror is joint perm[j] of the original)."""
        perm = np.arange(self.num_joints)
        for left, right in self.left_right_pairs:
            perm[left], perm[right] = right, left
        return perm

    def joint_index(self, name: str) -> int:
        try:
            return self.joint_names.index(name)
        except ValueError:
            raise ValueError(f"skeleton {self.name} has no joint {name!r}") from None


# HumanML3D's unit rest directions per joint (t2m raw offsets): SMPL's left is +x, the body faces +z, y is up.
_SMPL22_DIRECTIONS = np.array(
    [
        [0, 0, 0], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, -1, 0], [0, 1, 0], [0, -1, 0], [0, -1, 0],
        [0, 1, 0], [0, 0, 1], [0, 0, 1], [0, 1, 0], [1, 0, 0], [-1, 0, 0], [0, 0, 1], [0, -1, 0], [0, -1, 0],
        [0, -1, 0], [0, -1, 0], [0, -1, 0], [0, -1, 0],
    ],
    dtype=np.float64,
)

# Reference bone lengths (metres) of joints 1..21, measured on the HumanML3D sample 012314 (new_joints, median over
# its 170 frames; the spread is below 2e-6 m because HumanML3D retargets every clip to its reference skeleton).
_SMPL22_LENGTHS = np.array(
    [
        0.0, 0.1030740, 0.1098834, 0.1315682, 0.3936232, 0.3901882, 0.1431902, 0.4324330, 0.4256434, 0.0573647,
        0.1433818, 0.1494191, 0.2193600, 0.1374868, 0.1433828, 0.1030392, 0.1316140, 0.1229844, 0.2568399,
        0.2630919, 0.2660118, 0.2698763,
    ]
)

SMPL22 = Skeleton(
    name="smpl22",
    joint_names=(
        "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2", "left_ankle",
        "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar", "right_collar", "head",
        "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist",
    ),
    parents=(-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19),
    offsets=_SMPL22_DIRECTIONS * _SMPL22_LENGTHS[:, None],
    kinematic_chain=(
        (0, 2, 5, 8, 11), (0, 1, 4, 7, 10), (0, 3, 6, 9, 12, 15), (9, 14, 17, 19, 21), (9, 13, 16, 18, 20),
    ),
    left_right_pairs=((1, 2), (4, 5), (7, 8), (10, 11), (13, 14), (16, 17), (18, 19), (20, 21)),
    foot_joints=(7, 10, 8, 11),
    face_joints=(2, 1, 17, 16),
    feet_threshold=0.002,
    units_per_metre=1.0,
)

# KIT-ML (MMM marker skeleton, 21 joints) with HumanML3D's kit raw offsets and chains. Joint roles follow the indices
# HumanML3D's KIT processing uses (r_hip=11, l_hip=16, r_shoulder=5, l_shoulder=8, right foot 14/15, left 19/20).
_KIT21_DIRECTIONS = np.array(
    [
        [0, 0, 0], [0, 1, 0], [0, 1, 0], [0, 1, 0], [0, 1, 0], [1, 0, 0], [0, -1, 0], [0, -1, 0], [-1, 0, 0],
        [0, -1, 0], [0, -1, 0], [1, 0, 0], [0, -1, 0], [0, -1, 0], [0, 0, 1], [0, 0, 1], [-1, 0, 0], [0, -1, 0],
        [0, -1, 0], [0, 0, 1], [0, 0, 1],
    ],
    dtype=np.float64,
)

# Approximate bone lengths (metres) for a ~1.75 m adult. No KIT-ML clip is available here to measure HumanML3D's KIT
# reference skeleton, so these only matter for `normalize_joints(..., KIT21)`; features of real KIT-ML data do not
# depend on them. KIT-ML files are in millimetres: multiply metres by KIT21.units_per_metre.
_KIT21_LENGTHS = np.array(
    [
        0.0, 0.10, 0.20, 0.25, 0.12, 0.17, 0.28, 0.25, 0.17, 0.28, 0.25, 0.09, 0.42, 0.41, 0.06, 0.10, 0.09, 0.42,
        0.41, 0.06, 0.10,
    ]
)

KIT21 = Skeleton(
    name="kit21",
    joint_names=(
        "root", "pelvis", "thorax", "lower_neck", "head", "right_shoulder", "right_elbow", "right_wrist",
        "left_shoulder", "left_elbow", "left_wrist", "right_hip", "right_knee", "right_ankle", "right_metatarsal",
        "right_toe", "left_hip", "left_knee", "left_ankle", "left_metatarsal", "left_toe",
    ),
    parents=(-1, 0, 1, 2, 3, 3, 5, 6, 3, 8, 9, 0, 11, 12, 13, 14, 0, 16, 17, 18, 19),
    offsets=_KIT21_DIRECTIONS * _KIT21_LENGTHS[:, None],
    kinematic_chain=((0, 11, 12, 13, 14, 15), (0, 16, 17, 18, 19, 20), (0, 1, 2, 3, 4), (3, 5, 6, 7), (3, 8, 9, 10)),
    left_right_pairs=((5, 8), (6, 9), (7, 10), (11, 16), (12, 17), (13, 18), (14, 19), (15, 20)),
    foot_joints=(19, 20, 14, 15),
    face_joints=(11, 16, 5, 8),
    feet_threshold=0.05,
    units_per_metre=1000.0,
)

SKELETONS = {"smpl22": SMPL22, "kit21": KIT21}


def get_skeleton(name: str | Skeleton) -> Skeleton:
    """The skeleton called `name` (case-insensitive: smpl22 | kit21); a Skeleton is passed through."""
    if isinstance(name, Skeleton):
        return name
    try:
        return SKELETONS[str(name).lower()]
    except KeyError:
        raise ValueError(f"unknown skeleton {name!r}; expected one of: {', '.join(SKELETONS)}") from None
