"""Test motions turned to other headings: the field's exporters fail when a character faces backwards."""
from __future__ import annotations

import numpy as np


def yaw(joints: np.ndarray, degrees: float) -> np.ndarray:
    """The motion turned about the vertical axis (through the origin)."""
    a = np.radians(degrees)
    rotation = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    return joints @ rotation.T


def full_turn(joints: np.ndarray) -> np.ndarray:
    """The motion with its heading turning through 360 degrees over the clip, about the pelvis."""
    angles = np.linspace(0.0, 360.0, len(joints))
    centre = joints[:, :1] * np.array([1.0, 0.0, 1.0])
    return np.stack([yaw(frame - c, a) + c for frame, c, a in zip(joints, centre, angles)])
