"""The captioned CMU trials -> HumanML3D layout, on tiny synthetic trials written here (tests/model/cmu_synthetic.py):
DeepMimic forward kinematics and filling, the CC rig's T-pose frame, 20 fps, cuts at the sentences' timings, the
caption files, HumanML3D's split + val, the both-forms comparison, determinism and the cache, the CLI, merging.
One test (shared_data) builds a few real trials from the archive."""
from __future__ import annotations

import json
import tarfile
from pathlib import Path

import numpy as np
import pytest

from t2m.model.data.captions import parse_caption_line
from t2m.model.data.cmu_builder import CmuBuildOptions, build_cmu_dataset, cut_frames, val_trials
from t2m.model.data.cmu_source import CaptionedSegment, CmuTrial, drop_tpose, is_cmu_source, read_form, read_index
from t2m.model.data.merge import merge_datasets, merged_id
from t2m.model.data.motion_data import MotionDirectory
from t2m.motion.deepmimic import HUMANOID3D, read_deepmimic
from t2m.motion.deepmimic_smpl import TOE_OFFSET, humanoid3d_positions
from t2m.motion.features import joints_to_features, normalize_joints
from t2m.motion.skeleton import SMPL22
from tests.model.cmu_synthetic import SENTENCES, deepmimic_frames, write_cmu_tree, write_deepmimic
from tests.shared_data import require_shared


def _ids(root: Path, split: str) -> list[str]:
    return (root / f"{split}.txt").read_text().split()


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, dict]:
    """(the synthetic cmu-captioned directory, its build, the summary)."""
    base = tmp_path_factory.mktemp("cmu-synthetic")
    root = write_cmu_tree(base)
    out = base / "built"
    return root, out, build_cmu_dataset(root, out, CmuBuildOptions(progress=False))


def test_deepmimic_forward_kinematics_on_two_synthetic_frames(tmp_path: Path) -> None:
    frames = deepmimic_frames(2)
    frames[1][1:4] = [0.5, 0.9, 0.0]
    knee = 8 + 4 + 4 + 4  # root quat ends at 8; chest, neck, right_hip quaternions; then the right knee's angle
    frames[1][knee - 4:knee] = [1.0, 0.0, 0.0, 0.0]  # right hip straight
    frames[1][knee] = -np.pi / 2
    frames[0][knee] = 0.0  # the right leg straight at frame 0: its toe where TOE_OFFSET says
    motion = read_deepmimic(write_deepmimic(tmp_path / "two.txt", frames))
    assert motion.num_frames == 2 and motion.fps == pytest.approx(30.0)
    p = motion.positions
    chest, r_knee, r_ankle = (HUMANOID3D.index(n) for n in ("chest", "right_knee", "right_ankle"))
    np.testing.assert_allclose(p[0, chest] - p[0, 0], [0, 0.236151, 0], atol=1e-9)
    # a knee angle of -90 degrees about z puts the shin behind the knee (-x: the humanoid faces +x)
    np.testing.assert_allclose(p[1, r_ankle] - p[1, r_knee], [-0.40987, 0, 0], atol=1e-6)
    filled = humanoid3d_positions(motion)
    spine1, toe, ankle = (SMPL22.joint_index(n) for n in ("spine1", "right_foot", "right_ankle"))
    np.testing.assert_allclose(filled[0, spine1], p[0, 0] + [0, 0.236151 / 2, 0], atol=1e-9)
    np.testing.assert_allclose(filled[0, toe] - filled[0, ankle], TOE_OFFSET, atol=1e-9)  # ankle at rest
    assert filled[0, SMPL22.joint_index("left_collar"), 2] < 0 < filled[0, SMPL22.joint_index("right_collar"), 2]


def test_deepmimic_files_that_do_not_fit_get_one_line_errors(tmp_path: Path) -> None:
    short = [row[:-1] for row in deepmimic_frames(3)]
    with pytest.raises(ValueError, match=r"short\.txt: expected at least 2 frames of 44 numbers"):
        read_deepmimic(write_deepmimic(tmp_path / "short.txt", short))
    uneven = deepmimic_frames(3)
    uneven[0][0] = 0.05
    with pytest.raises(ValueError, match=r"uneven\.txt: expected every frame .* to last the same"):
        read_deepmimic(write_deepmimic(tmp_path / "uneven.txt", uneven))
    (tmp_path / "bad.txt").write_text("{}")
    with pytest.raises(ValueError, match=r"bad\.txt: expected DeepMimic JSON"):
        read_deepmimic(tmp_path / "bad.txt")


def test_the_t_pose_frame_is_dropped_and_the_rate_becomes_20_fps(synthetic) -> None:
    root, _, summary = synthetic
    trial = next(t for t in read_index(root.parent / "index.json") if t.trial_id == "01_01")
    joints, dropped = read_form(root, trial, "bvh")
    assert dropped and summary["tpose_dropped"] == ["01_01"]
    assert len(joints) == 50  # 150 motion frames at 60 fps span 2.483 s: 50 frames at 20 fps, the T-pose gone
    assert np.abs(joints[:, 0, 0]).max() < 0.01  # the T-pose frame stood 2.5 m off at x; no frame does now
    np.testing.assert_allclose(np.diff(joints[:, 0, 2]), 0.05, atol=1e-4)  # 1 m/s at 20 fps
    deepmimic, dropped = read_form(root, trial, "deepmimic")
    assert not dropped and len(deepmimic) == 50  # 75 frames at 30 fps
    still = np.zeros((5, 22, 3))
    assert drop_tpose(still)[1] is False


def test_cuts_honour_the_sentences_timings(synthetic) -> None:
    root, out, _ = synthetic
    trials = {t.trial_id: t for t in read_index(root.parent / "index.json")}
    joints, _ = read_form(root, trials["01_01"], "bvh")
    for clip_id, (start, stop) in (("01_01_000007", (10, 34)), ("01_01_000008", (0, 48))):
        segment = next(s for s in trials["01_01"].segments if clip_id.endswith(f"{s.humanml3d_id:06d}"))
        assert cut_frames(segment, len(joints)) == (start, stop)
        expected = joints_to_features(normalize_joints(joints[start:stop], SMPL22), SMPL22)
        np.testing.assert_allclose(np.load(out / "new_joint_vecs" / f"{clip_id}.npy"), expected, atol=1e-5)
    assert cut_frames(CaptionedSegment(1, "train", 1.0, 9.0, ("x",)), 100) == (20, 100)  # clipped to the motion


def test_caption_files_hold_the_sentences_in_humanml3d_format(synthetic) -> None:
    _, out, _ = synthetic
    lines = (out / "texts" / "01_01_000007.txt").read_text().splitlines()
    assert [parse_caption_line(line) for line in lines] == SENTENCES[7]
    caption, tokens, start, end = lines[0].split("#")
    assert caption == SENTENCES[7][0] and (start, end) == ("0.0", "0.0")
    assert tokens.split()[:3] == ["a/DET", "person/NOUN", "walk/VERB"]
    mirrored = (out / "texts" / "M01_01_000007.txt").read_text().splitlines()
    assert parse_caption_line(mirrored[0]) == "a person walks forward and raises the right hand"


def test_splits_follow_humanml3d_and_val_is_deterministic(synthetic) -> None:
    _, out, summary = synthetic
    assert _ids(out, "test") == ["01_01_000008", "M01_01_000008"]
    assert sorted(_ids(out, "train") + _ids(out, "val")) == ["01_01_000007", "02_02_000009", "M01_01_000007",
                                                             "M02_02_000009"]
    assert summary["splits"]["test"]["sentences"] == 3 and summary["sentences"] == 6
    assert summary["trials"]["with_sentences"] == 2 and summary["trials"]["in_index"] == 3
    trials = [CmuTrial(f"{k:02d}_01", {"bvh": "x.bvh"}, "", (CaptionedSegment(k, "train", 0, 1, ("a",)),))
              for k in range(100)]
    val = val_trials(trials)
    assert len(val) == 10 and val == val_trials(list(reversed(trials)))
    data = MotionDirectory(out, "train")
    assert data.feature_dim == 263 and data.captions(data.ids[0])


def test_both_forms_are_compared_and_one_kept(synthetic) -> None:
    _, _, summary = synthetic
    (comparison,) = summary["both_forms"]
    assert comparison["trial"] == "01_01" and comparison["kept"] in ("bvh", "deepmimic")
    assert comparison["frames"] == [50, 50] and comparison["root_relative_mpjpe_m"] > 0
    assert summary["trials"]["form_used"]["bvh"] + summary["trials"]["form_used"]["deepmimic"] == 2


def test_builds_are_deterministic_and_cached(synthetic, tmp_path: Path) -> None:
    root, first, _ = synthetic
    archive = tmp_path / "cmu-captioned-motion.tar.xz"
    with tarfile.open(archive, "w:xz") as tar:
        tar.add(root, arcname="cmu-captioned")
    (tmp_path / "index.json").write_bytes((root.parent / "index.json").read_bytes())
    assert is_cmu_source(archive) and is_cmu_source(root) and not is_cmu_source(tmp_path / "index.json")
    second = tmp_path / "again"
    build_cmu_dataset(archive, second, CmuBuildOptions(progress=False))
    files = sorted(p.relative_to(first) for p in first.rglob("*") if p.is_file() and p.name not in
                   ("build.log", "summary.json"))
    assert files == sorted(p.relative_to(second) for p in second.rglob("*") if p.is_file() and p.name not in
                           ("build.log", "summary.json"))
    for relative in files:
        assert (first / relative).read_bytes() == (second / relative).read_bytes(), relative
    cached = build_cmu_dataset(archive, second, CmuBuildOptions(progress=False))
    assert cached["cached"] and cached["build_key"] == json.loads((second / "summary.json").read_text())["build_key"]
    with pytest.raises(ValueError, match="already holds a dataset"):
        build_cmu_dataset(archive, second, CmuBuildOptions(progress=False, mirror=False))


def test_cli_builds_the_cmu_source_and_names_a_missing_index(synthetic, tmp_path: Path, capsys) -> None:
    from t2m.cli.main import main
    root, _, _ = synthetic
    assert main(["data", "build", "--source", str(root), "--out", str(tmp_path / "cli"), "--quiet", "--no-mirror"]) == 0
    out = capsys.readouterr().out
    assert "2 trials used of 2 with sentences" in out and "T-pose frame dropped: 01_01" in out
    assert main(["data", "build", "--source", str(root), "--out", str(tmp_path / "x"),
                 "--index", str(tmp_path / "nowhere.json")]) == 2
    assert "no CMU index found" in capsys.readouterr().err


def test_merge_prefixes_ids_and_keeps_mirrors_marked(synthetic, tmp_path: Path) -> None:
    _, built, _ = synthetic
    assert merged_id("cmu-", "M01_01_000007") == "Mcmu-01_01_000007"
    summary = merge_datasets([("a-", built), ("b-", built)], tmp_path / "merged")
    merged = tmp_path / "merged"
    assert "Ma-01_01_000008" in _ids(merged, "test") and "b-01_01_000008" in _ids(merged, "test")
    assert summary["splits"]["test"]["items"] == 4
    mirrored = built / "texts" / "M01_01_000008.txt"
    assert (merged / "texts" / "Mb-01_01_000008.txt").read_bytes() == mirrored.read_bytes()
    with pytest.raises(ValueError, match="distinct prefixes"):
        merge_datasets([("a-", built), ("a-", built)], tmp_path / "bad")


@pytest.mark.shared_data
def test_a_few_real_trials_build(tmp_path: Path) -> None:
    archive = require_shared("data", "cmu-captioned", "cmu-captioned-motion.tar.xz")
    summary = build_cmu_dataset(archive, tmp_path / "cmu", CmuBuildOptions(limit=4, progress=False, mirror=False))
    assert summary["trials"]["in_index"] == 133 and summary["trials"]["used"] == 4
    assert summary["clips"] >= 4 and not summary["checks"]["failed"]
    data = MotionDirectory(tmp_path / "cmu", "train")
    clip = data.joints(data.ids[0])
    assert clip.shape[1:] == (22, 3) and 0.0 <= clip[..., 1].min() < 0.05  # feet on the floor
