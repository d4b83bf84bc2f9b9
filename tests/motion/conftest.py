"""Fixtures for the motion-core tests: the real HumanML3D sample, committed in tests/fixtures/humanml3d-sample."""
from __future__ import annotations

import numpy as np
import pytest

from tests.shared_data import HUMANML3D_SAMPLE


@pytest.fixture(scope="session")
def humanml3d_sample() -> dict[str, np.ndarray]:
    """{'joints': [170, 22, 3], 'features': [170, 263]} of HumanML3D clip 012314 (float32, as stored)."""
    return {"joints": np.load(HUMANML3D_SAMPLE / "new_joints_012314.npy"),
            "features": np.load(HUMANML3D_SAMPLE / "new_joint_vecs_012314.npy")}
