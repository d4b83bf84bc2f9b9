"""`t2m motion ...`: conversions on real data, and one-line errors with a non-zero exit for bad input."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from t2m.cli.main import main

REPO = Path(__file__).resolve().parents[2]


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_features_to_joints_and_back(tmp_path, capsys, humanml3d_sample):
    features_path, joints_path = tmp_path / "f.npy", tmp_path / "out" / "j.npy"
    np.save(features_path, humanml3d_sample["features"])
    code, out, err = run(capsys, "motion", "joints", str(features_path), "-o", str(joints_path))
    assert code == 0, err
    assert "(170, 22, 3)" in out
    assert np.abs(np.load(joints_path) - humanml3d_sample["joints"]).max() < 1e-5

    again = tmp_path / "f2.npy"
    code, _, err = run(capsys, "motion", "features", str(joints_path), "-o", str(again), "--no-normalize")
    assert code == 0, err
    assert np.abs(np.load(again)[:80] - humanml3d_sample["features"][:80]).max() < 1e-5

    # normalising a moved copy first gives the same features
    moved = tmp_path / "moved.npy"
    np.save(moved, np.load(joints_path) + np.array([1.0, 0.5, -2.0], dtype=np.float32))
    normalised = tmp_path / "f3.npy"
    assert run(capsys, "motion", "features", str(moved), "-o", str(normalised))[0] == 0
    assert np.abs(np.load(normalised) - np.load(again)).max() < 1e-4


@pytest.mark.parametrize(
    "make_input, argv, message",
    [
        (lambda p: np.save(p / "x.npy", np.zeros((10, 262), np.float32)), ["joints", "x.npy"],
         "features must have shape [T, 263] with T >= 1, got (10, 262)"),
        (lambda p: np.save(p / "x.npy", np.zeros((10, 263), np.float32)), ["joints", "x.npy", "--skeleton", "kit21"],
         "features must have shape [T, 251]"),
        (lambda p: np.save(p / "x.npy", np.zeros((10, 22), np.float32)), ["features", "x.npy"],
         "joints must have shape [T, 22, 3]"),
        (lambda p: np.save(p / "x.npy", np.full((4, 22, 3), np.nan, np.float32)), ["features", "x.npy"],
         "joints contain NaN or inf"),
        (lambda p: None, ["joints", "missing.npy"], "file not found"),
        (lambda p: (p / "x.txt").write_text("1 2 3"), ["joints", "x.txt"], "expected a .npy file"),
        (lambda p: (p / "x.npy").write_text("not numpy"), ["features", "x.npy"], "not a readable .npy file"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, make_input, argv, message):
    make_input(tmp_path)
    argv = [str(tmp_path / a) if a.startswith(("x.", "missing")) else a for a in argv]
    code, _, err = run(capsys, "motion", *argv, "-o", str(tmp_path / "out.npy"))
    assert code == 2
    assert message in err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert not (tmp_path / "out.npy").exists()


def test_no_traceback_from_the_real_command(tmp_path):
    bad = tmp_path / "bad.npy"
    np.save(bad, np.zeros((3, 5), np.float32))
    command = [sys.executable, "-m", "t2m.cli", "motion", "joints", str(bad), "-o", str(tmp_path / "o.npy")]
    result = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        f"t2m motion: error: {bad}: features must have shape [T, 263] with T >= 1, got (3, 5)"
    ]


def test_from_bvh_on_a_real_bandai_namco_clip(tmp_path, capsys, bandai_clip):
    clip = bandai_clip("dataset-1_walk_normal_001")
    out = tmp_path / "walk.npy"
    code, _, err = run(capsys, "motion", "from-bvh", str(clip), "--map", "bandai-namco", "--fps", "20",
                       "-o", str(out))
    assert code == 0, err
    joints = np.load(out)
    frames_line = next(line for line in clip.read_text().splitlines() if line.startswith("Frames:"))
    frames_30fps = int(frames_line.split()[1])
    assert joints.shape == ((frames_30fps - 1) * 2 // 3 + 1, 22, 3)
    assert abs(joints[..., 1].min()) < 1e-6 and np.abs(joints[0, 0, [0, 2]]).max() < 1e-6
    # walking forward: the pelvis ends up well ahead along +Z
    assert joints[-1, 0, 2] > 1.0

    code, _, err = run(capsys, "motion", "from-bvh", str(tmp_path / "nope.bvh"), "-o", str(out))
    assert code == 2 and "file not found" in err
    broken = tmp_path / "broken.bvh"
    broken.write_text("HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0\n")
    code, _, err = run(capsys, "motion", "from-bvh", str(broken), "-o", str(out))
    assert code == 2 and "line" in err and err.count("\n") == 1
