"""The kinematic probes (t2m.model.evaluation.probes) and their runner (t2m/quality/probes.py).

(a) On real motion capture: each probe passes on a Bandai-Namco clip of its action (converted to SMPL-22 with
    motion.retarget, cut to the runner's 3 s) and fails on a clearly different one; one probe also on HumanML3D's
    own sample. These show the probes measure the right thing.
(b) On the shipped default model (t2m/bundles/default; skipped while it is absent): every probe's pass rate over several
    seeds and unseen phrasings is at least MODEL_MIN_PASS_RATE. These show the model follows the text.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from t2m.model.evaluation import probes
from t2m.motion.bvh import read_bvh
from t2m.motion.retarget import BANDAI_NAMCO, bvh_to_smpl22
from t2m.motion.transforms import mirror_joints
from tests.shared_data import HUMANML3D_SAMPLE

REPO = Path(__file__).resolve().parents[1]
HUMANML3D_JOINTS = HUMANML3D_SAMPLE / "new_joints_012314.npy"
PROBE_FRAMES = 60          # the runner's 3 s at 20 fps


@pytest.fixture(scope="module")
def clip(bandai_clip):
    """stem -> its first 3 s as SMPL-22 joints (the whole clip with `whole=True`)."""
    cache: dict[str, np.ndarray] = {}

    def joints(stem: str, whole: bool = False) -> np.ndarray:
        if stem not in cache:
            cache[stem] = bvh_to_smpl22(read_bvh(bandai_clip(stem)))
        return cache[stem] if whole else cache[stem][:PROBE_FRAMES]
    return joints


WALK = "dataset-1_walk_normal_001"
WALK_2 = "dataset-2_walk_active_024"
WALK_BACK = "dataset-1_walk-back_active_001"
RUN = "dataset-1_run_happy_001"
TURN_LEFT = "dataset-2_walk-turn-left_active_041"
TURN_RIGHT = "dataset-2_walk-turn-right_active_039"
RIGHT_HAND = "dataset-2_raise-up-right-hand_active_033"
LEFT_HAND = "dataset-2_wave-left-hand_youthful_007"
BOTH_HANDS = "dataset-2_wave-both-hands_active_029"
BOW = "dataset-1_bow_normal_001"
BYE = "dataset-1_bye_normal_001"
KICK = "dataset-1_kick_normal_001"


# ------------------------------------------------------------------ (a) real clips: pass on own, fail on contrast

@pytest.mark.parametrize("stem", [WALK, WALK_2])
def test_walk_forward_passes_on_walks(clip, stem):
    result = probes.probe_walk_forward(clip(stem))
    assert result.passed and result.value > 2.0, result


@pytest.mark.parametrize("stem", [WALK_BACK, BOW, RIGHT_HAND])
def test_walk_forward_fails_on_walking_back_and_standing(clip, stem):
    assert not probes.probe_walk_forward(clip(stem)).passed


@pytest.mark.parametrize("stem", [WALK_BACK, "dataset-1_walk-back_normal_001"])
def test_walk_backward_passes_on_walk_back(clip, stem):
    result = probes.probe_walk_backward(clip(stem))
    assert result.passed and result.value < -0.9, result


@pytest.mark.parametrize("stem", [WALK, RUN, BOW])
def test_walk_backward_fails_on_forward_and_standing(clip, stem):
    assert not probes.probe_walk_backward(clip(stem)).passed


def test_walk_back_on_humanml3d_sample():
    """HumanML3D 012314 walks backwards (while turning right) in frames 60-120, after a turning move to its left."""
    joints = np.load(HUMANML3D_JOINTS)
    backwards = joints[60:120]
    assert probes.probe_walk_backward(backwards).passed
    assert not probes.probe_walk_forward(backwards).passed
    assert probes.heading_change(backwards) < -45          # and it turns right on the way
    assert not probes.probe_walk_backward(joints[:60]).passed


def test_run_covers_more_ground_than_a_walk(clip):
    result = probes.probe_run_vs_walk(clip(RUN), clip(WALK))
    assert result.passed and result.details["run_path_m"] > result.details["walk_path_m"], result
    assert not probes.probe_run_vs_walk(clip(WALK), clip(RUN)).passed
    assert not probes.probe_run_vs_walk(clip(WALK_2), clip(WALK)).passed, "two walks are not a run and a walk"


def test_turn_left_and_right(clip):
    left, right = clip(TURN_LEFT), clip(TURN_RIGHT)
    assert probes.probe_turn(left, "left").passed and not probes.probe_turn(left, "right").passed
    assert probes.probe_turn(right, "right").passed and not probes.probe_turn(right, "left").passed
    assert not probes.probe_turn(clip(WALK), "left").passed and not probes.probe_turn(clip(WALK), "right").passed


def test_turn_follows_the_motion_not_the_label(clip):
    """This 'walk-turn-right' clip turns left (conftest notes the mislabel); the probe says so."""
    joints = clip("dataset-2_walk-turn-right_masculine_007", whole=True)
    assert probes.probe_turn(joints, "left").passed and not probes.probe_turn(joints, "right").passed


def test_turn_mirrored_is_the_other_turn(clip):
    mirrored = mirror_joints(clip(TURN_LEFT))
    assert probes.heading_change(mirrored) == pytest.approx(-probes.heading_change(clip(TURN_LEFT)), abs=1.0)
    assert probes.probe_turn(mirrored, "right").passed


@pytest.mark.parametrize("stem, passes", [(RIGHT_HAND, "right"), (LEFT_HAND, "left"), (BOTH_HANDS, "both")])
def test_raise_hand_passes_only_for_the_hand_used(clip, stem, passes):
    verdicts = {hands: probes.probe_raise_hand(clip(stem), hands).passed for hands in ("left", "right", "both")}
    assert verdicts == {hands: hands == passes for hands in verdicts}, verdicts


def test_raise_hand_mirrored_swaps_the_hand(clip):
    mirrored = mirror_joints(clip(LEFT_HAND))
    assert probes.probe_raise_hand(mirrored, "right").passed and not probes.probe_raise_hand(mirrored, "left").passed


@pytest.mark.parametrize("stem", [WALK, RUN, BYE])
def test_raise_hand_fails_with_hands_down(clip, stem):
    assert not any(probes.probe_raise_hand(clip(stem), hands).passed for hands in ("left", "right", "both"))


def test_bow(clip):
    result = probes.probe_bow(clip(BOW))
    assert result.passed and result.details["head_drop_m"] > 0.1, result
    for other in (WALK, RUN, BYE, RIGHT_HAND):
        assert not probes.probe_bow(clip(other)).passed, other


def test_kick(clip):
    result = probes.probe_kick(clip(KICK))
    assert result.passed and result.value > 0.8, result
    for other in (RUN, WALK, BOW):    # a run lifts a heel high, but behind the body
        assert not probes.probe_kick(clip(other)).passed, other


# ------------------------------------------------------------------ join smoothness

def test_join_smoothness_of_a_continuous_clip_is_small(clip):
    joints = clip(WALK, whole=True)
    joins = probes.join_smoothness(joints, [40, 83])
    assert joins.worst_ratio < 3.0 and max(joins.p95_ratios) < 1.5, joins


def test_join_smoothness_flags_a_cut(clip):
    """A walk followed by a bow placed back at the origin (two clips pasted): the pelvis jumps metres at the join."""
    walk, bow = clip(WALK), clip(BOW)
    joins = probes.join_smoothness(np.concatenate([walk, bow]), [len(walk)])
    assert joins.worst_ratio > 50, joins


def test_join_smoothness_flags_a_velocity_cut_without_a_position_jump(clip):
    """The bow moved to where the walk ends: positions are continuous, but the walking speed stops in one frame."""
    walk, bow = clip(WALK), clip(BOW).copy()
    bow[..., [0, 2]] += walk[-1, 0, [0, 2]] - bow[0, 0, [0, 2]]
    joins = probes.join_smoothness(np.concatenate([walk, bow]), [len(walk)])
    assert joins.worst_ratio > 10 and joins.p95_ratios[0] > 3, joins


def test_join_smoothness_rejects_joins_outside_the_motion(clip):
    with pytest.raises(ValueError, match="join_frames"):
        probes.join_smoothness(clip(WALK), [0])


def test_bad_input_names_the_field():
    with pytest.raises(ValueError, match="joints"):
        probes.probe_walk_forward(np.zeros((10, 21, 3)))
    with pytest.raises(ValueError, match="side"):
        probes.probe_turn(np.zeros((10, 22, 3)), "up")         # type: ignore[arg-type]
    with pytest.raises(ValueError, match="hands"):
        probes.probe_raise_hand(np.zeros((10, 22, 3)), "third")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="unknown probe"):
        probes.probe_by_name("fly")


def test_probe_sentences_are_not_training_captions(bandai_build):
    """The probes ask in words the model was not trained on: no phrasing is (part of) a caption that `t2m data build`
    writes (here for the fixture clips, mirrored; the next test covers every caption the templates can make)."""
    files = sorted((bandai_build / "texts").glob("*.txt"))
    assert len(files) >= 16, files
    captions = set()
    for name in files:
        with open(name, encoding="utf-8") as handle:
            captions.update(line.split("#")[0].strip().lower() for line in handle if line.strip())
    sentences = [p.lower() for spec in probes.PROBES for p in spec.phrasings + spec.reference_phrasings]
    sentences += [text.lower() for text, _, _ in probes.STREAM]
    assert len(probes.PROBES) == 10 and all(len(spec.phrasings) >= 3 for spec in probes.PROBES)
    for sentence in sentences:
        assert not any(sentence in caption for caption in captions), sentence


def test_probe_sentences_are_not_caption_templates():
    """The same without a built dataset: no probe phrasing is part of any sentence the caption templates can make,
    for every label, style and named hand, mirrored or not (the built captions are a subset of these)."""
    from t2m.model.data.captions import CONTENT_PHRASES, HANDED_PHRASES, STYLE_PHRASES, _candidates, mirror_caption

    templates: set[str] = set()
    for content in CONTENT_PHRASES:
        for style in STYLE_PHRASES:
            for side in (None, "left", "right") if content in HANDED_PHRASES else (None,):
                for group in _candidates(content, style, side):
                    templates.update(group)
    templates |= {mirror_caption(t) for t in templates}
    corpus = "\n".join(sorted(templates)).lower()
    sentences = [p.lower() for spec in probes.PROBES for p in spec.phrasings + spec.reference_phrasings]
    sentences += [text.lower() for text, _, _ in probes.STREAM]
    assert len(templates) > 10_000
    assert not [s for s in sentences if s in corpus]


# ------------------------------------------------------------------ the runner, on a random bundle (machinery only)

@pytest.fixture(scope="module")
def random_bundle(tmp_path_factory) -> Path:
    from t2m.families.gpt.random_bundle import build_random_bundle

    return build_random_bundle(tmp_path_factory.mktemp("probe-bundle") / "tiny")


@pytest.fixture(scope="module")
def random_engine(random_bundle):
    from t2m.runtime.engine import OnnxEngine

    return OnnxEngine.load(random_bundle, intra_op_threads=1)


def test_runner_report(random_engine):
    from t2m.quality.probes import format_report, run_probes

    report = run_probes(random_engine, seeds=[0, 1], guidance=2.0, probes=[probes.probe_by_name("run_vs_walk"),
                                                                           probes.probe_by_name("bow")],
                        progress=False)
    run_vs_walk = report.probe("run_vs_walk")
    assert len(run_vs_walk.trials) == len(probes.probe_by_name("run_vs_walk").phrasings) * 2
    assert all(set(t.details) == {"run_path_m", "walk_path_m"} for t in run_vs_walk.trials)
    assert 0.0 <= run_vs_walk.pass_rate <= 1.0
    assert report.stream is not None and np.asarray(report.stream.join_ratios).shape == (2, 2)
    assert set(report.stream.segment_pass_rates) == {"0:walk_forward", "1:raise_right", "2:bow"}
    table = format_report(report)
    assert "| run_vs_walk | > 1.25 |" in table and "join / p95" in table
    assert report.to_json()["probes"][0]["pass_rate"] == run_vs_walk.pass_rate


def test_runner_cli_writes_json(random_bundle, tmp_path, capsys):
    import json

    from t2m.quality.probes import main

    out = tmp_path / "probes.json"
    assert main(["--bundle", str(random_bundle), "--seeds", "2", "--probes", "kick,turn_left", "--no-stream",
                 "--json-out", str(out)]) == 0
    assert "| kick | > 0.4 m |" in capsys.readouterr().out
    data = json.loads(out.read_text())
    assert [row["probe"] for row in data["probes"]] == ["kick", "turn_left"] and data["stream"] is None
    assert len(data["probes"][0]["trials"]) == len(probes.probe_by_name("kick").phrasings) * 2


def test_runner_cli_refuses_a_bad_bundle_or_probe(random_bundle, tmp_path, capsys):
    from t2m.quality.probes import main

    assert main(["--bundle", str(tmp_path / "absent")]) == 2
    assert "absent" in capsys.readouterr().err
    assert main(["--bundle", str(random_bundle), "--probes", "fly"]) == 2
    assert "unknown probe 'fly'" in capsys.readouterr().err


# ------------------------------------------------------------------ (b) the shipped default model

DEFAULT_MODEL = REPO / "t2m" / "bundles" / "default"
MODEL_SEEDS = (0, 1, 2, 3, 4)          # the runner's default, so these are the model card's numbers
MODEL_MIN_PASS_RATE = 0.6
MODEL_MAX_MEAN_JOIN_P95_RATIO = 1.0   # on average over seeds, a join no sharper than the segments' own p95 change
REAL_WALK_CLIP = "dataset-1_walk_normal_001"   # the absolute reference for a join's velocity change
# What the default model (t2m-bandai-hifigpt-minilm 0.3.0) measurably does not do, as its model card says. Strict: if
# a retrained model passes, the XPASS fails the run and this list (and the card) must be updated.
KNOWN_FAILURES = {
    "turn_left": "turns for 'turns to her left while walking' and 'turns ninety degrees to the left' (1.0 each); "
                 "'veers round' 0.2; 'heads off', 'makes a sharp left', 'rounds a corner' 0.0 (pass rate 0.37)",
    "turn_right": "turns for 'turns to his right while walking' and 'turns ninety degrees to the right' (1.0 each); "
                  "'veers round' 0.6; 'heads off', 'makes a sharp right', 'rounds a corner' 0.0 (pass rate 0.43)",
}


@pytest.fixture(scope="module")
def default_report():
    if not (DEFAULT_MODEL / "manifest.json").is_file():
        pytest.skip(f"the default model is not committed yet ({DEFAULT_MODEL / 'manifest.json'} is absent)")
    from t2m.quality.probes import run_probes
    from t2m.runtime.engine import OnnxEngine

    engine = OnnxEngine.load(DEFAULT_MODEL)
    guidance = engine.limits.guidance()
    return run_probes(engine, MODEL_SEEDS, guidance, progress=False)


@pytest.mark.parametrize("name", [
    pytest.param(spec.name, marks=pytest.mark.xfail(strict=True, reason=KNOWN_FAILURES[spec.name]))
    if spec.name in KNOWN_FAILURES else spec.name for spec in probes.PROBES])
def test_default_model_follows_the_text(default_report, name):
    summary = default_report.probe(name)
    assert summary.pass_rate >= MODEL_MIN_PASS_RATE, (
        f"{name}: pass rate {summary.pass_rate:.2f} < {MODEL_MIN_PASS_RATE} ({summary.rule}); values "
        f"{[round(t.value, 2) for t in summary.trials]}")


def test_default_model_stream_joins_are_smooth(default_report, bandai_clip):
    """Per-sentence codes decoded once. At most one join of the seeds' streams changes the pelvis velocity from one
    frame to the next by more than a real normal walk does at its 95th percentile (two real clips pasted together
    jump by several m/s), and on average over seeds a join is no sharper than the segments' own 95th-percentile
    change. At most one, not none: it is a rate, the walk -> wave join of a few seeds stops abruptly (over seeds 0-59:
    4 of 60 for 0.3.0, 3 of 60 for 0.3.1, whose seed 4 is one; the wave -> bow join none)."""
    real_walk = bvh_to_smpl22(read_bvh(bandai_clip(REAL_WALK_CLIP)), BANDAI_NAMCO, target_fps=20)
    real_p95 = probes.join_smoothness(real_walk, ()).within_p95
    changes = np.asarray(default_report.stream.join_changes)             # [seeds, joins], m/s per frame
    assert (changes >= real_p95).sum() <= 1, (changes, real_p95)
    mean_ratios = np.asarray(default_report.stream.join_p95_ratios).mean(axis=0)
    assert mean_ratios.max() < MODEL_MAX_MEAN_JOIN_P95_RATIO, mean_ratios


@pytest.mark.parametrize("asked, opposite, measure", [
    ("walk_forward", "walk_backward", lambda t: t.value),
    ("turn_left", "turn_right", lambda t: t.value),
    ("raise_right", "raise_left", lambda t: t.details["right_up_fraction"]),
    ("raise_left", "raise_right", lambda t: t.details["left_up_fraction"]),
])
def test_default_model_tells_opposites_apart(default_report, asked, opposite, measure):
    """Weaker than a pass rate, but it fails for a text-blind model: the asked direction measures more than its
    opposite (walks further forward, turns further left, lifts that hand more often)."""
    asked_mean = np.mean([measure(t) for t in default_report.probe(asked).trials])
    opposite_mean = np.mean([measure(t) for t in default_report.probe(opposite).trials])
    assert asked_mean > opposite_mean, f"{asked}: {asked_mean:.2f} vs {opposite}: {opposite_mean:.2f}"
