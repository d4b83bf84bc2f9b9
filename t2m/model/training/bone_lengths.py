"""Bone lengths read straight off HumanML3D features, differentiably.

Why: the decoder predicts root-relative joint positions (the "ric" channels) freely, so nothing keeps a bone at one
length from frame to frame, and generated skeletons stretch by several centimetres. Bone lengths are invariant to
the heading rotation and to the root's ground-plane position, so they can be measured on the ric channels with the
root at (0, height, 0), without integrating the root trajectory: cheap enough for a training loss.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

HEIGHT_CHANNEL = 3  # root height; channels 0-2 are the root's angular and planar velocities
RIC_START = 4


class BoneLengths(torch.nn.Module):
    """Normalised features [..., T, D] -> bone lengths in metres [..., T, J-1] (bone j joins joint j to its parent)."""

    # buffers (registered in __init__)
    mean: torch.Tensor
    std: torch.Tensor
    child_joints: torch.Tensor
    parent_joints: torch.Tensor

    def __init__(self, mean: np.ndarray, std: np.ndarray, parents: Sequence[int]) -> None:
        super().__init__()
        joints = len(parents)
        if mean.shape[-1] != 12 * joints - 1:
            raise ValueError(f"{mean.shape[-1]} feature channels do not fit a {joints}-joint skeleton (12 J - 1)")
        self.joints = joints
        self.register_buffer("mean", torch.as_tensor(np.asarray(mean, np.float32)))
        self.register_buffer("std", torch.as_tensor(np.asarray(std, np.float32)))
        self.register_buffer("child_joints", torch.arange(1, joints))
        self.register_buffer("parent_joints", torch.as_tensor(list(parents[1:])))

    def forward(self, normalised: torch.Tensor) -> torch.Tensor:
        features = normalised * self.std + self.mean
        height = features[..., HEIGHT_CHANNEL : HEIGHT_CHANNEL + 1]
        zeros = torch.zeros_like(height)
        root = torch.cat([zeros, height, zeros], dim=-1).unsqueeze(-2)
        ric = features[..., RIC_START : RIC_START + 3 * (self.joints - 1)]
        joints = torch.cat([root, ric.reshape(*ric.shape[:-1], self.joints - 1, 3)], dim=-2)
        return (joints[..., self.child_joints, :] - joints[..., self.parent_joints, :]).norm(dim=-1)
