"""The committed fixtures (tests/fixtures): licences and README beside the data, and, where the shared folder is
present (marked shared_data), byte-for-byte copies of the shared files they come from."""
from __future__ import annotations

import json
import re
import tarfile

import pytest

from tests.shared_data import BANDAI_FIXTURE, FIXTURES, HUMANML3D_SAMPLE, require_shared

BANDAI_ROOT = BANDAI_FIXTURE.parent
HUMANML3D_FILES = ("LICENSE", "Mean.npy", "Std.npy", "new_joint_vecs_012314.npy", "new_joints_012314.npy")
MAX_FIXTURE_BYTES = 5_000_000


def _bandai_members() -> list[str]:
    """The fixture files of the archive, as archive member names (dataset/Bandai-Namco-Research-...)."""
    return sorted(str(p.relative_to(BANDAI_ROOT)) for p in BANDAI_FIXTURE.rglob("*") if p.is_file())


def test_fixtures_carry_their_licences_and_stay_small():
    assert sorted(p.name for p in HUMANML3D_SAMPLE.iterdir()) == sorted(HUMANML3D_FILES)
    assert "MIT License" in (HUMANML3D_SAMPLE / "LICENSE").read_text()
    assert (BANDAI_ROOT / "LICENSE").read_text().startswith("Attribution-NonCommercial 4.0 International")
    readme = (FIXTURES / "README.md").read_text()
    assert "CC BY-NC 4.0" in readme and "Bandai Namco Research Inc." in readme and "MIT" in readme
    total = sum(p.stat().st_size for p in FIXTURES.rglob("*") if p.is_file())
    assert total < MAX_FIXTURE_BYTES, f"tests/fixtures holds {total} bytes: keep the fixtures small"


def test_readme_lists_exactly_the_bandai_clips():
    listed = set(re.findall(r"^\| (dataset-[12]_\S+) \| (\d+) \|", (FIXTURES / "README.md").read_text(), re.M))
    clips = {p.stem: p for p in BANDAI_FIXTURE.rglob("*.bvh")}
    assert {stem for stem, _ in listed} == set(clips)
    for stem, frames in listed:
        header = re.search(r"^Frames:\s*(\d+)$", clips[stem].read_text(), re.M)
        assert header is not None and header.group(1) == frames, stem
    labelled = {p.stem for p in BANDAI_FIXTURE.rglob("*.json")}
    assert labelled == {stem for stem in clips if stem.startswith("dataset-1_")}
    assert all(set(json.loads(p.read_text())) == {"content", "style"} for p in BANDAI_FIXTURE.rglob("*.json"))


@pytest.mark.shared_data
def test_humanml3d_fixture_is_the_shared_sample():
    shared = require_shared("data", "humanml3d-sample")
    for name in HUMANML3D_FILES:
        assert (HUMANML3D_SAMPLE / name).read_bytes() == (shared / name).read_bytes(), name


@pytest.mark.shared_data
def test_bandai_fixture_files_are_unmodified_archive_members():
    """One pass over the archive that stops once every fixture file was seen (they all sit in its first ~10%)."""
    archive = require_shared("data", "bandai-namco", "bandai-namco-motion.tar.xz")
    assert (BANDAI_ROOT / "LICENSE").read_bytes() == (archive.parent / "LICENSE").read_bytes()
    wanted = set(_bandai_members())
    assert len(wanted) == 16 + 9 + 2
    with tarfile.open(archive, "r:xz") as tar:
        for member in tar:
            if member.name in wanted:
                source = tar.extractfile(member)
                assert source is not None
                assert source.read() == (BANDAI_ROOT / member.name).read_bytes(), member.name
                wanted.discard(member.name)
                if not wanted:
                    break
    assert not wanted, f"not in {archive}: {sorted(wanted)}"
