"""Shared fixtures: a handful of real Bandai-Namco clips extracted once per test session.

The shared folder is $T2M_SHARED, else `<repo>/../shared`. Reading one member of a .tar.xz means decompressing
everything before it, so the fixture extracts only the members below, in one pass that stops as soon as all of them
were seen (they sit in the first ~8% of the archive: about a second). Tests that need them skip, naming the path,
when the archive is absent.
"""
from __future__ import annotations

import os
import tarfile
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

# dataset-1 clips with their labels (so the dataset builder can run on them) + a few dataset-2 BVH files
BANDAI_TEST_CLIPS = (
    "Bandai-Namco-Research-Motiondataset-1/data/dataset-1_walk_normal_001",
    "Bandai-Namco-Research-Motiondataset-1/data/dataset-1_walk-back_active_001",
    "Bandai-Namco-Research-Motiondataset-1/data/dataset-1_walk-left_normal_001",
    "Bandai-Namco-Research-Motiondataset-1/data/dataset-1_bow_normal_001",
    "Bandai-Namco-Research-Motiondataset-1/data/dataset-1_bye_normal_001",
    "Bandai-Namco-Research-Motiondataset-1/data/dataset-1_run_happy_001",
    "Bandai-Namco-Research-Motiondataset-1/data/dataset-1_walk-right_tired_001",
    "Bandai-Namco-Research-Motiondataset-1/data/dataset-1_kick_normal_001",
    "Bandai-Namco-Research-Motiondataset-1/data/dataset-1_walk-back_normal_001",
    "Bandai-Namco-Research-Motiondataset-2/data/dataset-2_walk_active_024",
    "Bandai-Namco-Research-Motiondataset-2/data/dataset-2_walk-turn-left_active_041",
    "Bandai-Namco-Research-Motiondataset-2/data/dataset-2_walk-turn-right_active_039",
    "Bandai-Namco-Research-Motiondataset-2/data/dataset-2_walk-turn-right_masculine_007",  # mislabelled: turns left
    "Bandai-Namco-Research-Motiondataset-2/data/dataset-2_wave-left-hand_youthful_007",
    "Bandai-Namco-Research-Motiondataset-2/data/dataset-2_raise-up-right-hand_active_033",
    "Bandai-Namco-Research-Motiondataset-2/data/dataset-2_wave-both-hands_active_029",
)
# dataset-2's JSON sidecars (and label files) sit far later in the archive than its BVH files: BVH only for those.
BANDAI_TEST_FILES = tuple(f"{clip}{ext}" for clip in BANDAI_TEST_CLIPS
                          for ext in ((".bvh", ".json") if "dataset-1_" in clip else (".bvh",))) + (
    "Bandai-Namco-Research-Motiondataset-1/cfg/content_label.txt",
    "Bandai-Namco-Research-Motiondataset-1/cfg/style_label.txt",
)


def shared_root() -> Path:
    return Path(os.environ.get("T2M_SHARED", REPO / ".." / "shared")).resolve()


def bandai_archive() -> Path:
    return shared_root() / "data" / "bandai-namco" / "bandai-namco-motion.tar.xz"


@pytest.fixture(scope="session")
def bandai_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Directory laid out like the unpacked archive (`dataset/Bandai-Namco-Research-Motiondataset-N/...`), holding
    only BANDAI_TEST_FILES. Its `extract_seconds.txt` records how long the extraction took."""
    archive = bandai_archive()
    if not archive.is_file():
        pytest.skip(f"Bandai-Namco archive not found at {archive} (set T2M_SHARED to the shared folder)")
    target = tmp_path_factory.mktemp("bandai")
    wanted = {f"dataset/{name}" for name in BANDAI_TEST_FILES}
    started = time.perf_counter()
    with tarfile.open(archive, "r:xz") as tar:
        for member in tar:
            if member.name in wanted:
                tar.extract(member, target, filter="data")
                wanted.discard(member.name)
                if not wanted:
                    break
    if wanted:
        pytest.fail(f"{archive} lacks test members: {sorted(wanted)[:3]}")
    (target / "extract_seconds.txt").write_text(f"{time.perf_counter() - started:.2f}\n")
    return target / "dataset"


@pytest.fixture(scope="session")
def bandai_clip(bandai_dir: Path):
    """clip stem -> path of its .bvh among the extracted test clips."""
    def path(stem: str) -> Path:
        dataset = stem.split("_")[0].removeprefix("dataset-")
        result = bandai_dir / f"Bandai-Namco-Research-Motiondataset-{dataset}" / "data" / f"{stem}.bvh"
        assert result.is_file(), f"{stem} is not among conftest.BANDAI_TEST_CLIPS"
        return result
    return path
