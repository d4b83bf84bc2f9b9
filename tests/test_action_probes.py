"""The CMU actions' probes (t2m.model.evaluation.action_probes): each passes on a motion that does its
action and fails on the fixture clips that do not, and (with the shared data) on the captioned CMU clips at the
rates its docstring states. Synthetic actions are made from a real standing clip so that only the probed quantity
changes."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from t2m.model.evaluation.action_probes import ACTION_PROBES, probe_get_up, probe_invert, probe_jump
from t2m.motion.bvh import read_bvh
from t2m.motion.retarget import bvh_to_smpl22
from t2m.quality.probes import calibrate_on_cmu, main
from tests.shared_data import require_shared

OTHERS = ["dataset-1_walk_normal_001", "dataset-1_run_happy_001", "dataset-1_bow_normal_001",
          "dataset-1_kick_normal_001", "dataset-2_wave-both-hands_active_029", "dataset-1_bye_normal_001"]


@pytest.fixture(scope="module")
def clip(bandai_clip):
    return lambda stem: bvh_to_smpl22(read_bvh(bandai_clip(stem)))[:60]


@pytest.fixture(scope="module")
def standing(clip) -> np.ndarray:
    """The first second of a bow clip, before the bow: 20 frames of a person standing, repeated to 3 s."""
    still = clip("dataset-1_bow_normal_001")[:20]
    return np.concatenate([still, still[::-1], still])


def _hop(standing: np.ndarray, height: float) -> np.ndarray:
    """The whole body raised on a parabola of `height` metres over frames 20-31 (a jump, nothing else changed)."""
    joints = standing.copy()
    t = np.linspace(0.0, 1.0, 12)
    joints[20:32, :, 1] += (4 * height * t * (1 - t))[:, None]
    return joints


@pytest.mark.parametrize("stem", OTHERS)
def test_no_action_probe_passes_on_the_fixture_clips(clip, stem):
    joints = clip(stem)
    assert not [spec.name for spec in ACTION_PROBES if spec.check(joints).passed]


def test_jump_needs_both_feet_off_and_the_pelvis_up(standing):
    assert probe_jump(_hop(standing, 0.35)).passed
    assert not probe_jump(_hop(standing, 0.06)).passed       # control: a bob, not a jump
    assert not probe_jump(standing).passed


def test_invert_is_feet_over_head(standing):
    pelvis = standing[:, :1, 1]
    upside_down = standing.copy()
    upside_down[30:40, :, 1] = 2 * pelvis[30:40] - standing[30:40, :, 1] + 0.9     # flipped about the pelvis
    result = probe_invert(upside_down)
    assert result.passed and result.value > 0.5
    assert not probe_invert(standing).passed


def test_get_up_starts_low_and_ends_standing(standing):
    ramp = np.linspace(0.25, 1.0, len(standing))[:, None]
    rising = standing.copy()
    rising[..., 1] *= ramp                                    # from a crouch near the floor to standing
    assert probe_get_up(rising).passed
    assert not probe_get_up(rising[::-1]).passed              # control: sitting down is not getting up
    assert not probe_get_up(standing).passed


def test_unknown_probe_names_the_known_ones(capsys):
    assert main(["--probes", "jump,somersault", "--bundle", "t2m/bundles/default"]) == 2
    error = capsys.readouterr().err
    assert "somersault" in error and "get_up" in error and "walk_forward" in error


@pytest.mark.shared_data
def test_calibration_on_the_captioned_cmu_clips(tmp_path: Path):
    """The rates in action_probes' docstring, on a fresh build of every captioned trial (about 15 s)."""
    from t2m.model.data.cmu_builder import CmuBuildOptions, build_cmu_dataset

    archive = require_shared("data", "cmu-captioned", "cmu-captioned-motion.tar.xz")
    build_cmu_dataset(archive, tmp_path / "cmu", CmuBuildOptions(progress=False))
    rates = calibrate_on_cmu(tmp_path / "cmu")
    assert rates["jump"]["own_rate"] >= 0.85 and rates["jump"]["other_rate"] <= 0.25
    assert rates["invert"]["own_rate"] >= 0.85 and rates["invert"]["other_rate"] <= 0.05
    assert rates["get_up"]["own_rate"] >= 0.5 and rates["get_up"]["other_rate"] <= 0.02
    captions = {line.split("#")[0].strip().lower() for path in (tmp_path / "cmu" / "texts").glob("*.txt")
                for line in path.read_text().splitlines() if line.strip()}
    assert captions and not [p for spec in ACTION_PROBES for p in spec.phrasings if p.lower() in captions]
