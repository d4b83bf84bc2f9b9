"""Body parts as token columns of a joint-token map, for POST /edit's `body_part` edits (the masked family).

A joint-token map (MoGenTS's 2D layout, t2m.model.networks.joint_vqvae) has C columns per time step: the joint axis
in skeleton order, zero-padded to a multiple of the group size 2**down_j (half the padding before, as MoGenTS pads:
22 -> 1 + 22 + 1), then grouped, so column c holds the joints of padded slots c*g .. c*g + g - 1. A part names joints;
its columns are those whose joints are mostly (more than half) the part's: on SMPL-22 with 6 columns "upper_body" is
the neck and collars, head, shoulders, elbows and wrists (columns 3-5) and "lower_body" the pelvis and hips, ankles
and left foot (columns 0 and 2); column 1 (spine1, spine2, both knees) belongs to neither, so an edit of one half
keeps it. A map of one column (MoMask's 1D tokens) or a layout that does not match has no parts.

The diffusion family edits feature channels instead (`part_channels`): in HumanML3D's layout (t2m/motion/features.py:
root 4, ric 3(J-1), rotations 6(J-1), velocities 3J, foot contacts 4) "lower_body" is the root's channels, the lower
joints' ric, rotation and velocity channels and the foot contacts, exactly MDM's HML_LOWER_BODY_MASK (its edit.py
upper_body mode keeps those and regenerates the rest), and "upper_body" every other channel.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["BODY_PARTS", "joint_columns", "part_channels", "part_columns"]

UPPER = ("spine3", "neck", "left_collar", "right_collar", "head", "left_shoulder", "right_shoulder", "left_elbow",
         "right_elbow", "left_wrist", "right_wrist", "spine1", "spine2")
LOWER = ("pelvis", "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle", "left_foot",
         "right_foot")
BODY_PARTS: dict[str, tuple[str, ...]] = {"upper_body": UPPER, "lower_body": LOWER}
MAX_GROUP_BITS = 4   # groups of up to 16 joints per column


def joint_columns(num_joints: int, columns: int) -> list[tuple[int, ...]] | None:
    """The joints (indices) of each column of a [rows, columns] joint-token map of `num_joints` joints, or None when
    no grouping of MoGenTS's layout gives `columns` columns of more than one."""
    if columns < 2:
        return None
    for bits in range(MAX_GROUP_BITS + 1):
        group = 2**bits
        padding = -num_joints % group
        if (num_joints + padding) // group != columns:
            continue
        before = padding // 2
        return [tuple(j for j in range(c * group - before, (c + 1) * group - before) if 0 <= j < num_joints)
                for c in range(columns)]
    return None


def part_columns(joint_names: Sequence[str], columns: int) -> dict[str, tuple[int, ...]]:
    """Each body part's columns (those mostly of its joints), for the parts that have some and leave some kept."""
    groups = joint_columns(len(joint_names), columns)
    if groups is None:
        return {}
    parts = {}
    for part, names in BODY_PARTS.items():
        chosen = tuple(c for c, joints in enumerate(groups)
                       if joints and 2 * sum(joint_names[j] in names for j in joints) > len(joints))
        if 0 < len(chosen) < columns:
            parts[part] = chosen
    return parts


def part_channels(joint_names: Sequence[str], features: int) -> dict[str, tuple[int, ...]]:
    """Each body part's feature channels of a HumanML3D feature row of `features` channels (12 J - 1 for J joints,
    joint 0 the root), or {} for another layout."""
    joints = len(joint_names)
    if joints < 2 or features != 12 * joints - 1:
        return {}
    lower = np.zeros(features, bool)
    lower[:4] = True                                        # root: rotation velocity, x/z velocity, height
    ric, rot, vel = 4, 4 + 3 * (joints - 1), 4 + 9 * (joints - 1)
    for joint, name in enumerate(joint_names):
        if name not in BODY_PARTS["lower_body"]:
            continue
        if joint > 0:
            lower[ric + 3 * (joint - 1):ric + 3 * joint] = True
            lower[rot + 6 * (joint - 1):rot + 6 * joint] = True
        lower[vel + 3 * joint:vel + 3 * joint + 3] = True
    lower[features - 4:] = True                             # foot contacts
    return {"upper_body": tuple(int(c) for c in np.flatnonzero(~lower)),
            "lower_body": tuple(int(c) for c in np.flatnonzero(lower))}
