"""Foot skating: a planted foot that slides is measured, one that stays or lifts is not."""
from __future__ import annotations

import numpy as np
import pytest

from t2m.model.evaluation.foot_skating import TOES, foot_skating


def _still(frames: int = 40) -> np.ndarray:
    joints = np.zeros((frames, 22, 3))
    joints[:, :, 1] = 0.9            # everything well above the floor...
    joints[:, TOES, 1] = 0.0         # ...but the toes, on it
    return joints


def test_planted_still_feet_do_not_skate():
    result = foot_skating(_still())
    assert result.planted_frames == 2 * 39 and result.mean_speed_m_s == 0.0 and result.sliding_fraction == 0.0


def test_a_planted_foot_sliding_forward_is_measured():
    joints = _still()
    joints[:, TOES[0], 2] = np.arange(40) * 0.05       # 5 cm a frame at 20 fps = 1 m/s, on the floor
    result = foot_skating(joints, fps=20)
    assert result.mean_speed_m_s == pytest.approx(0.5)   # one foot at 1 m/s, the other still
    assert result.sliding_fraction == pytest.approx(0.5)


def test_a_lifted_moving_foot_is_not_skating():
    joints = _still()
    joints[:, TOES[0], 2] = np.arange(40) * 0.05
    joints[:, TOES[0], 1] = 0.3                        # swinging in the air
    result = foot_skating(joints, fps=20)
    assert result.planted_frames == 39 and result.sliding_fraction == 0.0


def test_bad_shapes_are_refused():
    with pytest.raises(ValueError, match=r"joints must be \[T >= 2, 22, 3\]"):
        foot_skating(np.zeros((1, 22, 3)))
