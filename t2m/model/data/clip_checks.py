"""Sanity checks on one built clip: a wrong joint map, unit or floor shows up here before it reaches training.

Each check is a number with a limit; a clip that fails one is listed in summary.json (and, where two conversions of
the same trial exist, the one with fewer failures is kept). The limits are loose on purpose: they catch broken
conversions (a leg of 3 m, a body floating above the floor, feet that never touch it), not unusual motion (jumps,
cartwheels and rolls pass).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from t2m.motion.skeleton import SMPL22

__all__ = ["CHECK_LIMITS", "ClipChecks", "check_clip"]

FOOT_JOINTS = (7, 8, 10, 11)   # ankles and toe bases
CONTACT_CHANNELS = slice(259, 263)
CHECK_LIMITS = {
    "source_leg_m": (0.6, 1.2),        # hip-knee-ankle length before retargeting: metres, an adult's leg
    "contact_share": (0.05, 1.0),      # feature frames with a foot contact: the feet touch the floor sometimes
    "floor_gap_m": (0.0, 0.15),        # median over frames of the lowest foot joint's height: no floating body
    "bone_error_m": (0.0, 0.01),       # recovered joints' bone lengths against SMPL-22's reference lengths
}


@dataclass(frozen=True)
class ClipChecks:
    source_leg_m: float
    contact_share: float
    floor_gap_m: float
    bone_error_m: float

    @property
    def failed(self) -> list[str]:
        """Names of the checks outside their limits."""
        return [name for name, (low, high) in CHECK_LIMITS.items() if not low <= getattr(self, name) <= high]

    def as_dict(self) -> dict[str, float]:
        return {name: round(float(getattr(self, name)), 4) for name in CHECK_LIMITS}


def _leg_length(joints: np.ndarray) -> float:
    hip, knee, ankle = joints[0, 1], joints[0, 4], joints[0, 7]
    return float(np.linalg.norm(knee - hip) + np.linalg.norm(ankle - knee))


def check_clip(source_joints: np.ndarray, features: np.ndarray, recovered: np.ndarray) -> ClipChecks:
    """Checks of a clip from its joints before normalisation, its features and the joints recovered from them."""
    bones = np.linalg.norm(recovered[:, 1:] - recovered[:, list(SMPL22.parents[1:])], axis=-1)
    reference = np.linalg.norm(SMPL22.offsets[1:], axis=-1)
    return ClipChecks(
        source_leg_m=_leg_length(source_joints),
        contact_share=float((features[:, CONTACT_CHANNELS] > 0.5).any(axis=1).mean()),
        floor_gap_m=float(np.median(recovered[:, list(FOOT_JOINTS), 1].min(axis=1))),
        bone_error_m=float(np.abs(bones - reference).max()),
    )
