"""Fixtures the training tests share."""
from __future__ import annotations

from pathlib import Path

import pytest

from tests.model.synthetic_motion_data import make_dataset


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small synthetic dataset in the HumanML3D layout, one per test module (trainers write caches beside it)."""
    return make_dataset(tmp_path_factory.mktemp("motion_data"))
