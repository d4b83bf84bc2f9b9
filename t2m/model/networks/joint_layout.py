"""The HumanML3D feature vector as a joints x 12 map (MoGenTS's 2D layout), and back, exactly.

A frame of J joints has 12 J - 1 features (263 for SMPL-22, 251 for KIT-21):

    [0:4] root (yaw velocity, XZ velocity, height)   [4 : 4+3(J-1)] root-relative positions of joints 1..J-1
    [.. : +6(J-1)] 6D rotations of joints 1..J-1      [.. : +3J] local velocities of all joints   [-4:] foot contacts

Per joint the map holds 12 numbers: [0:3] position, [3:9] rotation, [9:12] velocity. The root has no position or
rotation of its own, so its first nine slots carry what MoGenTS's decoder reads there: [0:4] the root features,
[4:8] the foot contacts, [8] nothing (always 0). Every feature lands in exactly one slot, so
``joint_map_to_features(features_to_joint_map(x)) == x`` bit for bit. Both directions are a single gather, which
exports to ONNX as one Gather node.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
import torch

PER_JOINT = 12
UNUSED_SLOT = (0, 8)  # (joint, slot) that holds no feature


def joints_for_dim(feat_dim: int) -> int:
    """263 -> 22, 251 -> 21 (D = 12 J - 1)."""
    if feat_dim < 23 or (feat_dim + 1) % PER_JOINT:
        raise ValueError(f"feature dimension {feat_dim} is not a HumanML3D-style layout (12 J - 1 with J >= 2)")
    return (feat_dim + 1) // PER_JOINT


@lru_cache(maxsize=8)
def joint_map_index(num_joints: int) -> np.ndarray:
    """[J, 12] int64: the feature index each slot holds; -1 for the unused root slot."""
    j = num_joints
    positions, rotations = 4, 4 + 3 * (j - 1)
    velocities = rotations + 6 * (j - 1)
    contacts = velocities + 3 * j
    index = np.full((j, PER_JOINT), -1, dtype=np.int64)
    index[0, 0:4] = np.arange(0, 4)
    index[0, 4:8] = np.arange(contacts, contacts + 4)
    for joint in range(1, j):
        index[joint, 0:3] = positions + 3 * (joint - 1) + np.arange(3)
        index[joint, 3:9] = rotations + 6 * (joint - 1) + np.arange(6)
    for joint in range(j):
        index[joint, 9:12] = velocities + 3 * joint + np.arange(3)
    index.setflags(write=False)
    return index


@lru_cache(maxsize=8)
def _gather_index(num_joints: int) -> np.ndarray:
    """Flat [J * 12] index into the features with one zero appended (the unused slot reads that zero)."""
    flat = joint_map_index(num_joints).reshape(-1).copy()
    flat[flat < 0] = 12 * num_joints - 1  # = feat_dim: the appended zero
    return flat


@lru_cache(maxsize=8)
def _scatter_index(num_joints: int) -> np.ndarray:
    """[feat_dim]: for each feature, its position in the flat map."""
    flat = joint_map_index(num_joints).reshape(-1)
    inverse = np.empty(12 * num_joints - 1, dtype=np.int64)
    used = np.nonzero(flat >= 0)[0]
    inverse[flat[used]] = used
    return inverse


def features_to_joint_map(features: torch.Tensor) -> torch.Tensor:
    """[..., 12 J - 1] -> [..., J, 12] (the unused root slot is 0)."""
    joints = joints_for_dim(features.shape[-1])
    index = torch.as_tensor(_gather_index(joints), device=features.device)
    padded = torch.cat([features, torch.zeros_like(features[..., :1])], dim=-1)
    return padded.index_select(-1, index).reshape(*features.shape[:-1], joints, PER_JOINT)


def joint_map_to_features(joint_map: torch.Tensor) -> torch.Tensor:
    """[..., J, 12] -> [..., 12 J - 1] (the unused root slot is ignored)."""
    joints = joint_map.shape[-2]
    if joint_map.shape[-1] != PER_JOINT:
        raise ValueError(f"a joint map has {PER_JOINT} features per joint, got {joint_map.shape[-1]}")
    index = torch.as_tensor(_scatter_index(joints), device=joint_map.device)
    return joint_map.reshape(*joint_map.shape[:-2], joints * PER_JOINT).index_select(-1, index)
