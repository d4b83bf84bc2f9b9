"""Fixtures for the motion-core tests: the real HumanML3D sample from the project's shared folder.

The shared folder is found via $T2M_SHARED, else `<repo>/../shared`; tests that need it skip (with the path they
looked at) when it is absent.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]


def shared_dir() -> Path:
    return Path(os.environ.get("T2M_SHARED", REPO / ".." / "shared")).resolve()


@pytest.fixture(scope="session")
def humanml3d_sample() -> dict[str, np.ndarray]:
    """{'joints': [170, 22, 3], 'features': [170, 263]} of HumanML3D clip 012314 (float32, as stored)."""
    folder = shared_dir() / "data" / "humanml3d-sample"
    joints_path, features_path = folder / "new_joints_012314.npy", folder / "new_joint_vecs_012314.npy"
    if not (joints_path.is_file() and features_path.is_file()):
        pytest.skip(f"HumanML3D sample not found in {folder} (set T2M_SHARED to the shared folder)")
    return {"joints": np.load(joints_path), "features": np.load(features_path)}
