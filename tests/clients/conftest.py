"""Fixtures for the real-client suite (marked `clients`): our exports of the real HumanML3D sample, on disk.

Install the clients with scripts/install_clients.sh; each test skips with the reason when its client is absent.
"""
from __future__ import annotations

import numpy as np
import pytest

from tests.headings import full_turn, yaw
from tests.shared_data import HUMANML3D_SAMPLE


@pytest.fixture(scope="session")
def sample_joints() -> np.ndarray:
    """[170, 22, 3] joints of HumanML3D clip 012314 (metres), from tests/fixtures."""
    return np.load(HUMANML3D_SAMPLE / "new_joints_012314.npy").astype(np.float64)


@pytest.fixture(scope="session")
def motions(sample_joints) -> dict[str, np.ndarray]:
    """The clips every client reads: a full 360-degree turn, and the mirrored clip facing backwards."""
    from t2m.motion.transforms import mirror_joints

    return {"turn": full_turn(sample_joints), "mirrored_backwards": yaw(mirror_joints(sample_joints), 180.0)}
