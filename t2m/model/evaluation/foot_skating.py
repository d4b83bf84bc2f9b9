"""Foot skating: a foot that slides while it should be planted, the artefact in-betweening and joins are known for.

A toe joint (SMPL-22's left_foot / right_foot) counts as planted on a frame when it is within `contact_m` of the
motion's floor (the lowest toe height over the motion, so a motion need not start on y = 0); its horizontal speed
on those frames is the skating. Reported: the mean planted speed (m/s) and the fraction of planted frames sliding
faster than `slide_m_s`. Thresholds follow the common practice of the in-betweening literature (5 cm contact
height, 2.5 cm per frame at 20 fps = 0.5 m/s); they are this project's choice, not a published protocol.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from t2m.motion.constants import FPS
from t2m.motion.skeleton import SMPL22

__all__ = ["FootSkating", "foot_skating"]

TOES = (SMPL22.joint_names.index("left_foot"), SMPL22.joint_names.index("right_foot"))


@dataclass(frozen=True)
class FootSkating:
    planted_frames: int          # toe-frames within the contact height (both feet counted)
    mean_speed_m_s: float        # their mean horizontal speed
    sliding_fraction: float      # the share of them faster than the slide threshold


def foot_skating(joints: np.ndarray, fps: float = FPS, contact_m: float = 0.05,
                 slide_m_s: float = 0.5) -> FootSkating:
    """Skating of the toes of `joints` [T, 22, 3] (metres, Y up); T >= 2."""
    array = np.asarray(joints, np.float64)
    if array.ndim != 3 or array.shape[1:] != (len(SMPL22.joint_names), 3) or len(array) < 2:
        raise ValueError(f"joints must be [T >= 2, {len(SMPL22.joint_names)}, 3], got {array.shape}")
    toes = array[:, TOES, :]                                            # [T, 2, 3]
    floor = toes[:, :, 1].min()
    speed = np.linalg.norm(np.diff(toes[:, :, [0, 2]], axis=0), axis=-1) * fps   # [T-1, 2]
    low = np.maximum(toes[:-1, :, 1], toes[1:, :, 1]) - floor <= contact_m     # planted over the whole step
    planted = speed[low]
    if planted.size == 0:
        return FootSkating(0, 0.0, 0.0)
    return FootSkating(int(planted.size), float(planted.mean()), float((planted > slide_m_s).mean()))
