"""t2m.model.data.dataset_builder + t2m.model.data.motion_data on real Bandai-Namco clips: HumanML3D layout, shapes,
mirrors with swapped captions, disjoint deterministic splits, identical output for any worker count."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from t2m.model.data.captions import mirror_caption, parse_caption_line
from t2m.model.data.dataset_builder import (
    STD_FLOOR,
    BuildOptions,
    assign_splits,
    build_dataset,
    feature_statistics,
    find_clips,
    observed_side,
)
from t2m.model.data.motion_data import MotionDirectory
from t2m.motion.features import features_to_joints
from t2m.motion.skeleton import SMPL22
from t2m.motion.transforms import mirror_joints


@pytest.fixture(scope="module")
def builds(bandai_dir: Path, bandai_build: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, dict]:
    """The same 8-clip build twice: with 2 workers here, and with 1 (conftest's bandai_build)."""
    first = tmp_path_factory.mktemp("build2")
    summary = build_dataset(bandai_dir, first, BuildOptions(workers=2, limit=8, progress=False))
    return first, bandai_build, summary


def _ids(root: Path, split: str) -> list[str]:
    return (root / f"{split}.txt").read_text().split()


def test_layout_and_shapes(builds) -> None:
    root, _, summary = builds
    assert summary["clips_used"] == 8 and summary["clips_found"] == 9  # only dataset-1 has its labels in the fixture
    for name in ("new_joints", "new_joint_vecs", "texts", "Mean.npy", "Std.npy", "train.txt", "val.txt", "test.txt",
                 "summary.json"):
        assert (root / name).exists(), name
    all_ids = _ids(root, "train") + _ids(root, "val") + _ids(root, "test")
    assert len(all_ids) == summary["items"] == 2 * sum(s["source_clips"] for s in summary["splits"].values()) + 2
    for item in all_ids:
        features = np.load(root / "new_joint_vecs" / f"{item}.npy")
        joints = np.load(root / "new_joints" / f"{item}.npy")
        assert features.dtype == np.float32 and joints.dtype == np.float32
        assert features.ndim == 2 and features.shape[1] == 263 and features.shape[0] >= 19
        assert joints.shape == (features.shape[0], 22, 3)  # HumanML3D: joints recovered from the features
        np.testing.assert_allclose(features_to_joints(features, SMPL22), joints, atol=1e-5)
        lines = (root / "texts" / f"{item}.txt").read_text().splitlines()
        assert len(lines) >= 5 and len(set(lines)) == len(lines)
        for line in lines:
            caption, tokens, start, end = line.split("#")
            assert caption and all("/" in t for t in tokens.split()) and (start, end) == ("0.0", "0.0")
    mean, std = np.load(root / "Mean.npy"), np.load(root / "Std.npy")
    assert mean.shape == std.shape == (263,) and mean.dtype == np.float32 and std.min() >= STD_FLOOR
    assert json.loads((root / "summary.json").read_text())["license"] == "CC BY-NC 4.0"


def test_long_clips_are_cut_into_pieces(builds) -> None:
    root, _, _ = builds
    pieces = sorted(i for i in _ids(root, "train") + _ids(root, "val") + _ids(root, "test")
                    if i.startswith("dataset-1_kick_normal_001"))
    assert pieces == ["dataset-1_kick_normal_001_p0", "dataset-1_kick_normal_001_p1"]  # 358 frames at 30 fps
    for item in pieces:
        assert len(np.load(root / "new_joints" / f"{item}.npy")) <= 196


def test_mirrors_share_the_split_and_swap_left_right(builds) -> None:
    root, _, _ = builds
    for split in ("train", "val", "test"):
        ids = set(_ids(root, split))
        originals = {i for i in ids if not i.startswith("M")}
        assert {f"M{i}" for i in originals} == ids - originals
        for item in originals:
            captions = (root / "texts" / f"{item}.txt").read_text().splitlines()
            mirrored = (root / "texts" / f"M{item}.txt").read_text().splitlines()
            assert [parse_caption_line(c) for c in mirrored] == [mirror_caption(parse_caption_line(c))
                                                                 for c in captions]
            joints = np.load(root / "new_joints" / f"{item}.npy")
            mirrored_joints = np.load(root / "new_joints" / f"M{item}.npy")
            np.testing.assert_allclose(mirrored_joints, mirror_joints(joints, SMPL22), atol=1e-4)
    walk_left = (root / "texts" / "dataset-1_walk-left_normal_001.txt").read_text()
    assert "left" in walk_left and "right" not in walk_left.split("#")[0]
    assert "right" in (root / "texts" / "Mdataset-1_walk-left_normal_001.txt").read_text().split("\n")[0]


def test_splits_are_disjoint_and_deterministic(builds) -> None:
    first, second, _ = builds
    splits = [set(_ids(first, s)) for s in ("train", "val", "test")]
    assert not (splits[0] & splits[1] or splits[0] & splits[2] or splits[1] & splits[2])
    files = sorted(p.relative_to(first) for p in first.rglob("*") if p.is_file() and p.name != "build.log")
    assert files == sorted(p.relative_to(second) for p in second.rglob("*") if p.is_file() and p.name != "build.log")
    for relative in files:
        assert (first / relative).read_bytes() == (second / relative).read_bytes(), relative


def test_split_assignment_is_stratified_and_exact() -> None:
    from t2m.model.data.dataset_builder import ClipSource
    clips = [ClipSource(f"c{c}_{s}_{k}", "", f"c{c}", f"s{s}") for c in range(3) for s in range(2) for k in range(20)]
    splits = assign_splits(clips)
    assert sorted(splits.values()).count("val") == 12 and sorted(splits.values()).count("test") == 12
    for c in range(3):
        for s in range(2):
            group = [splits[f"c{c}_{s}_{k}"] for k in range(20)]
            assert group.count("train") == 16 and group.count("val") == 2 and group.count("test") == 2
    assert assign_splits(list(reversed(clips))) == splits


def test_short_clips_are_skipped_with_a_reason(bandai_dir: Path, tmp_path: Path) -> None:
    summary = build_dataset(bandai_dir, tmp_path / "strict", BuildOptions(workers=1, limit=3, mirror=False,
                                                                          min_frames=100, progress=False))
    reasons = {s["clip"]: s["reason"] for s in summary["skipped"]}
    assert reasons == {"dataset-1_bow_normal_001": "too short: 92 frames at 20 fps < 100"}  # 138 at 30 fps
    assert not any(p.name.startswith("M") for p in (tmp_path / "strict" / "texts").iterdir())
    with pytest.raises(ValueError, match="already holds a dataset"):
        build_dataset(bandai_dir, tmp_path / "strict", BuildOptions(workers=1, limit=1, progress=False))


def test_labels_come_from_the_sidecars(bandai_dir: Path) -> None:
    clips = {c.clip_id: c for c in find_clips(bandai_dir)}
    assert (clips["dataset-1_walk-back_active_001"].content, clips["dataset-1_walk-back_active_001"].style) == \
        ("walk-back", "active")
    with pytest.raises(ValueError, match="no Bandai-Namco dataset found"):
        find_clips(bandai_dir / "Bandai-Namco-Research-Motiondataset-1" / "cfg")


def test_observed_side_on_real_gestures(builds) -> None:
    root, _, _ = builds
    bye = np.load(root / "new_joints" / "dataset-1_bye_normal_001.npy")
    assert observed_side("bye", bye) == "right"  # the actor waves with the right hand
    assert observed_side("bye", mirror_joints(bye, SMPL22)) == "left"
    walk_left = np.load(root / "new_joints" / "dataset-1_walk-left_normal_001.npy")
    assert observed_side("walk-left", walk_left) == "left"
    assert "right hand" in (root / "texts" / "dataset-1_bye_normal_001.txt").read_text()


def test_feature_statistics_average_groups_and_floor() -> None:
    rows = np.random.default_rng(0).normal(size=(50, 263)).astype(np.float32)
    rows[:, 259:] = 0.0  # contacts never change
    mean, std = feature_statistics([rows[:20], rows[20:]])
    np.testing.assert_allclose(mean, rows.mean(0), atol=1e-6)
    assert np.all(std[4:67] == std[4]) and np.all(std[259:] == STD_FLOOR)
    with pytest.raises(ValueError, match="no training feature rows"):
        feature_statistics([])


def test_motion_directory_reads_the_build(builds) -> None:
    root, _, _ = builds
    data = MotionDirectory(root, "train")
    assert data.skeleton == "smpl22" and data.feature_dim == 263 and len(data) == len(_ids(root, "train"))
    item = data.ids[0]
    assert data.features(item).shape[1] == 263 and data.joints(item).shape[1:] == (22, 3)
    assert data.num_frames(item) == len(data.features(item))
    assert len(data.captions(item)) >= 5 and "#" not in data.captions(item)[0]
    normalised = data.normalized_features(item)
    np.testing.assert_allclose(normalised * data.std + data.mean, data.features(item), atol=1e-5)


def _fake_layout(root: Path, dim: int, joints: int) -> None:
    for sub in ("new_joint_vecs", "new_joints", "texts"):
        (root / sub).mkdir(parents=True)
    np.save(root / "Mean.npy", np.zeros(dim, np.float32))
    np.save(root / "Std.npy", np.ones(dim, np.float32))
    np.save(root / "new_joint_vecs" / "000001.npy", np.zeros((30, dim), np.float32))
    np.save(root / "new_joints" / "000001.npy", np.zeros((30, joints, 3), np.float32))
    (root / "texts" / "000001.txt").write_text("a person walks.#a/DET person/NOUN walk/VERB#0.0#nan\n")
    (root / "train.txt").write_text("000001\n000002\n")  # 000002 has no files: dropped and counted


def test_motion_directory_reads_kit_layout_and_names_problems(tmp_path: Path) -> None:
    kit = tmp_path / "kit"
    _fake_layout(kit, 251, 21)
    data = MotionDirectory(kit, "train")
    assert data.skeleton == "kit21" and data.ids == ["000001"] and data.missing == 1
    assert data.captions("000001") == ["a person walks."]
    with pytest.raises(ValueError, match=r"val\.txt is missing \(split 'val'\); splits present: train"):
        MotionDirectory(kit, "val")
    with pytest.raises(ValueError, match="does not exist"):
        MotionDirectory(tmp_path / "nowhere")
    odd = tmp_path / "odd"
    _fake_layout(odd, 100, 22)
    with pytest.raises(ValueError, match="feature dim 100"):
        MotionDirectory(odd, "train")
    (odd / "Mean.npy").unlink()
    with pytest.raises(ValueError, match=r"Mean\.npy is missing"):
        MotionDirectory(odd, "train")
    broken = tmp_path / "broken"
    _fake_layout(broken, 263, 22)
    np.save(broken / "new_joints" / "000001.npy", np.zeros((30, 21, 3), np.float32))
    with pytest.raises(ValueError, match=r"expected \[frames, 22, 3\]"):
        MotionDirectory(broken, "train").joints("000001")


def test_cli_builds_and_reports_bad_sources_in_one_line(bandai_dir: Path, tmp_path: Path, capsys) -> None:
    from t2m.cli.main import main
    assert main(["data", "build", "--source", str(bandai_dir), "--out", str(tmp_path / "cli"), "--limit", "2",
                 "--no-mirror", "--workers", "1", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "2 clips used of 9 found" in out and "CC BY-NC 4.0" in out
    assert main(["data", "build", "--source", str(tmp_path / "missing.tar.xz"), "--out", str(tmp_path / "x")]) == 2
    assert main(["data", "build", "--source", str(tmp_path), "--out", str(tmp_path / "y"), "--quiet"]) == 2
    errors = capsys.readouterr().err.strip().splitlines()
    assert errors[0].startswith("t2m data: error: file not found:") and "missing.tar.xz" in errors[0]
    assert errors[1].startswith("t2m data: error:") and "no Bandai-Namco dataset found" in errors[1]
    assert main(["data", "build", "--source", str(bandai_dir), "--out", str(tmp_path / "z"), "--workers", "0"]) == 2


def test_a_mislabelled_turn_is_caught(bandai_clip) -> None:
    """dataset-2_walk-turn-right_masculine_007 turns left (so do walk-turn-left_masculine_006/007 the other way):
    the builder captions such clips with the mirrored label."""
    from t2m.motion.bvh import read_bvh
    from t2m.motion.retarget import bvh_to_smpl22
    mislabelled = bvh_to_smpl22(read_bvh(bandai_clip("dataset-2_walk-turn-right_masculine_007")))
    assert observed_side("walk-turn-right", mislabelled) == "left"
    correct = bvh_to_smpl22(read_bvh(bandai_clip("dataset-2_walk-turn-right_active_039")))
    assert observed_side("walk-turn-right", correct) == "right"
    assert observed_side("walk-turn-left", mirror_joints(correct, SMPL22)) == "left"
