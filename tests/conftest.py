"""Shared fixtures: the committed real clips (tests/fixtures), and the shared-data marker's hooks.

The Bandai-Namco clips in tests/fixtures/bandai-namco/dataset are laid out like the unpacked archive
(`Bandai-Namco-Research-Motiondataset-N/data/*.bvh`); dataset-1's clips come with their JSON labels and cfg/ label
files, so the dataset builder runs on them, dataset-2's are BVH only (tests/fixtures/README.md). Tests that need the
whole shared folder are marked `shared_data` (tests/shared_data.py).
"""
from __future__ import annotations

from pathlib import Path

import pytest

from tests.shared_data import (  # noqa: F401  (the shared_data marker's hooks, registered by being here)
    BANDAI_FIXTURE,
    pytest_runtest_makereport,
    pytest_runtest_setup,
)


@pytest.fixture(scope="session")
def bandai_dir() -> Path:
    """The fixture clips' `dataset` directory (read-only: build into tmp_path)."""
    return BANDAI_FIXTURE


@pytest.fixture(scope="session")
def bandai_clip(bandai_dir: Path):
    """clip stem -> path of its .bvh among the fixture clips."""
    def path(stem: str) -> Path:
        dataset = stem.split("_")[0].removeprefix("dataset-")
        result = bandai_dir / f"Bandai-Namco-Research-Motiondataset-{dataset}" / "data" / f"{stem}.bvh"
        assert result.is_file(), f"{stem} is not among the fixture clips ({bandai_dir})"
        return result
    return path


@pytest.fixture(scope="session")
def bandai_build(bandai_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """What `t2m data build --limit 8` makes of the fixture clips (1 worker, mirrored): the HumanML3D layout with
    captions, for the tests that need a built dataset."""
    from t2m.model.data.dataset_builder import BuildOptions, build_dataset

    root = tmp_path_factory.mktemp("bandai-build")
    build_dataset(bandai_dir, root, BuildOptions(workers=1, limit=8, progress=False))
    return root
