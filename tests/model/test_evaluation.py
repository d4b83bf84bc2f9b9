"""`t2m eval` and `t2m train evaluator` end to end on a tiny dataset with tiny random models, plus the stream
helpers."""
from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from t2m.model.evaluation.evaluate import (
    FRAMES_PER_TOKEN,
    Clips,
    EvalOptions,
    draw,
    pelvis_velocity_jumps,
    stream_metrics,
    windows,
    windows_at_joins,
)
from tests.model.synthetic_motion_data import _source_motion, make_dataset

ROWS = ("Real motion", "VQ reconstruction", "Generation (guidance=1)", "Generation (guidance=3)",
        "Streams (guidance=1)", "Streams (guidance=3)", "Real crops pasted (hard cuts)",
        "Real crops' VQ codes, decoded once")


class HashTextEncoder:
    """Stand-in for MiniLM: a fixed random unit vector per caption. Loading BERT takes ~20 s on these shared
    cores and the text model is not what these tests check (tests marked slow use the real one)."""

    name = "minilm"
    dim = 384

    def encode(self, texts: list[str], batch_size: int = 128) -> np.ndarray:
        rows = [np.random.default_rng(int(hashlib.sha256(t.encode()).hexdigest()[:8], 16)).normal(size=self.dim)
                for t in texts]
        rows = np.array(rows, dtype=np.float32).reshape(len(texts), self.dim)
        return rows / np.linalg.norm(rows, axis=1, keepdims=True).clip(1e-8)


@pytest.fixture(autouse=True)
def one_thread():
    torch.set_num_threads(1)


@pytest.fixture
def fast_text(request, monkeypatch):
    if "slow" not in request.keywords:
        monkeypatch.setattr("t2m.model.networks.text_encoders.get_text_encoder",
                            lambda name, **kwargs: HashTextEncoder())


@pytest.fixture(scope="module")
def tiny_runs(tmp_path_factory) -> dict[str, Path]:
    """A 12-clip dataset whose test split lists every clip, and random tiny VQ / GPT / evaluator checkpoints."""
    from t2m.families.gpt.network import GPTConfig, MotionGPT
    from t2m.model.networks.evaluator import EvaluatorConfig, MotionEvaluator
    from t2m.model.networks.vqvae import MotionVQVAE, VQConfig
    from t2m.model.training.checkpoint import save_checkpoint

    root = tmp_path_factory.mktemp("eval")
    data = make_dataset(root / "data", train_clips=8, val_clips=3)
    ids = [line for split in ("train", "val", "test") for line in (data / f"{split}.txt").read_text().split()]
    (data / "test.txt").write_text("\n".join(ids) + "\n")
    torch.manual_seed(0)
    runs = {"data": data, "vq": root / "vq", "gpt": root / "gpt", "evaluator": root / "evaluator"}
    save_checkpoint(runs["vq"], MotionVQVAE(VQConfig(width=16, code_dim=8, nb_code=16, depth=1)), 0)
    save_checkpoint(runs["gpt"], MotionGPT(GPTConfig(codebook_size=16, embed=16, n_head=2, n_layer_base=1,
                                                     n_layer_head=1)), 0, {"text_encoder": {"kind": "minilm"}})
    evaluator = MotionEvaluator(EvaluatorConfig(width=16, n_layer=1, n_head=2, embed_dim=8))
    save_checkpoint(runs["evaluator"], evaluator, 0)
    return runs


def _eval_args(runs: dict[str, Path], out: Path, *extra: str) -> list[str]:
    return ["eval", "--data", str(runs["data"]), "--evaluator", str(runs["evaluator"]), "--vq", str(runs["vq"]),
            "--gpt", str(runs["gpt"]), "--limit", "10", "--repeats", "2", "--mm-texts", "3", "--mm-repeats", "2",
            "--guidance", "1", "3", "--out", str(out), "--quiet", *extra]


@pytest.mark.parametrize("text", ["hashed", pytest.param("minilm", marks=pytest.mark.slow)])
def test_eval_writes_every_row_with_finite_numbers(tiny_runs, tmp_path, capsys, fast_text, text):
    from t2m.cli.main import main

    out = tmp_path / "report.md"
    assert main(_eval_args(tiny_runs, out)) == 0
    report = out.read_text()
    assert report in capsys.readouterr().out
    for row in ROWS:
        assert f"| {row} |" in report
    assert "nan" not in report.lower()
    result = json.loads(out.with_suffix(".json").read_text())
    summary = result["summary"]
    assert len(result["repeats"]) == 2 and result["counts"]["clips"] == 10
    expected = {"real": {"top1", "top2", "top3", "fid", "mm_dist", "diversity"},
                "recon": {"top1", "fid", "mm_dist", "diversity", "mpjpe_mm"},
                "gen_g1": {"top1", "top3", "fid", "mm_dist", "diversity", "mmodality"},
                "gen_g3": {"top1", "fid", "mmodality"},
                "multi_g1": {"sliding_fid", "transition_fid", "pelvis_jump_joins", "pelvis_jump_within"},
                "multi_g3": {"sliding_fid", "transition_fid", "pelvis_jump_joins", "pelvis_jump_within"},
                "pasted": {"sliding_fid", "transition_fid", "pelvis_jump_joins", "pelvis_jump_within"},
                "pasted_codes": {"sliding_fid", "transition_fid", "pelvis_jump_joins", "pelvis_jump_within"}}
    for row, keys in expected.items():
        for key in keys:
            mean, half = summary[row][key]
            assert math.isfinite(mean) and math.isfinite(half) and half >= 0, (row, key)
    # The real data against itself: a smaller FID than a random VQ's reconstruction, and R-precision in [0, 1].
    assert summary["real"]["fid"][0] < summary["recon"]["fid"][0]
    assert 0.0 <= summary["gen_g1"]["top1"][0] <= summary["gen_g1"]["top3"][0] <= 1.0


def test_stream_metrics_see_a_hard_cut_and_not_a_seamless_one():
    """The reference rows' measure on real motion (HumanML3D's sample): pasting a clip's frames 0-60 to its frames
    60-120 is no cut at all, pasting them to frames 120-170 is a hard cut, and only the second jumps at the join."""
    features, _, _ = _source_motion()
    seamless = features[0:120]
    cut = np.concatenate([features[0:60], features[120:170]])
    options = EvalOptions()
    metrics_seamless = stream_metrics(None, [seamless], [[60, 60]], options, real_window_emb=None)
    metrics_cut = stream_metrics(None, [cut], [[60, 50]], options, real_window_emb=None)
    assert metrics_cut["pelvis_jump_joins"] > 2 * metrics_seamless["pelvis_jump_joins"], (metrics_cut, metrics_seamless)
    assert metrics_seamless["pelvis_jump_joins"] < 3 * metrics_seamless["pelvis_jump_within"]
    assert "transition_fid" not in metrics_cut  # no real windows given: no FID


def test_eval_names_a_checkpoint_of_the_wrong_kind(tiny_runs, tmp_path, capsys):
    from t2m.cli.main import main

    args = _eval_args(tiny_runs, tmp_path / "r.md")
    args[args.index("--evaluator") + 1] = str(tiny_runs["vq"])
    assert main(args) == 2
    assert "expected a evaluator checkpoint" in capsys.readouterr().err


def test_training_batches_and_validation_on_the_tiny_dataset(tiny_runs):
    from t2m.model.data.motion_data import MotionDirectory
    from t2m.model.networks.evaluator import EvaluatorConfig, MotionEvaluator
    from t2m.model.training.train_evaluator import load_pairs, make_step_fn, make_val_fn, training_batches

    reader = MotionDirectory(tiny_runs["data"], "train")
    captions = sorted({c for i in reader.ids for c in reader.captions(i)})
    text = dict(zip(captions, HashTextEncoder().encode(captions)))
    pairs = load_pairs(reader, text, reader.mean, reader.std)
    assert len(pairs.ids) == len(reader.ids)
    features, lengths, text_features = next(training_batches(pairs, batch_size=4, max_frames=100, unit=4, seed=0))
    assert features.shape[0] == 4 and features.shape[2] == 263 and text_features.shape == (4, 384)
    assert int(lengths.max()) == features.shape[1] <= 100 and all(int(n) % 4 == 0 for n in lengths)
    model = MotionEvaluator(EvaluatorConfig(width=16, n_layer=1, n_head=2, embed_dim=8))
    loss, values, count = make_step_fn(0.95)(model, (features, lengths, text_features))
    assert torch.isfinite(loss) and count == 4 and 0 <= values["batch_acc"] <= 1
    scores = make_val_fn(pairs, 196, 4, batch_size=4, fn_threshold=0.95)(model)
    assert set(scores) == {"loss", "r1", "r3"} and 0 <= scores["r1"] <= scores["r3"] <= 1


@pytest.mark.slow  # the shared training loop imports torch._dynamo (AdamW) and matplotlib: ~15 s on shared cores
def test_train_evaluator_cli_writes_a_loadable_checkpoint(tiny_runs, tmp_path, fast_text):
    from t2m.cli.main import main
    from t2m.model.training.checkpoint import load_model, read_run_config

    run = tmp_path / "ev"
    code = main(["train", "evaluator", "--data", str(tiny_runs["data"]), "--out", str(run), "--steps", "2",
                 "--batch-size", "4", "--val-every", "2", "--width", "16", "--layers", "1", "--embed-dim", "8"])
    assert code == 0
    assert read_run_config(run)["step"] == 2
    log = (run / "log.csv").read_text().splitlines()
    assert "val_r1" in log[0] and len(log) == 2
    model = load_model(run, expect_kind="evaluator")
    assert not torch.equal(model.std, torch.ones_like(model.std))  # the dataset's statistics travel with it


def test_pelvis_velocity_jump_sees_a_step_at_the_join_only():
    # The pelvis moves at 1 m/s along x, then jumps 0.5 m at frame 20 and continues at 1 m/s.
    frames = 40
    joints = np.zeros((frames, 22, 3))
    joints[:, 0, 0] = np.arange(frames) / 20.0 + 0.5 * (np.arange(frames) >= 20)
    at_joins, inside = pelvis_velocity_jumps(joints, joins=[20])
    assert at_joins.shape == (1,) and at_joins[0] == pytest.approx(0.5 * 20)  # 10 m/s change of velocity
    np.testing.assert_allclose(inside, 0.0, atol=1e-9)


def test_windows_and_draws():
    motion = np.zeros((200, 263), np.float32)
    assert len(windows(motion, 80, 40)) == 4          # starts 0, 40, 80, 120
    assert [len(w) for w in windows_at_joins(motion, [30, 100, 170], 80)] == [80]  # only the join at 100 fits
    rng = np.random.default_rng(0)
    clips = Clips(["a", "b"], [np.zeros((250, 263), np.float32), np.zeros((37, 263), np.float32)],
                  [["x", "y"], ["z"]])
    sample = draw(clips, max_frames=196, rng=rng)
    assert [len(m) for m in sample.motions] == [196, 36]
    assert sample.tokens == [196 // FRAMES_PER_TOKEN, 9]
    assert sample.captions[1] == "z"


def test_mpjpe_root_relative_ignores_a_root_offset_that_global_mpjpe_counts():
    """A 10 cm root step in the first frame's velocity moves the whole body 10 cm from frame 1 on (the pose is the
    same): global MPJPE counts it, root-relative MPJPE does not."""
    import numpy as np

    from t2m.model.evaluation.evaluate import mpjpe_mm

    rng = np.random.default_rng(0)
    real = [rng.normal(size=(24, 263)).astype(np.float32) * 0.05 for _ in range(3)]
    shifted = [clip.copy() for clip in real]
    for clip in shifted:
        clip[0, 1] += 0.1
    assert abs(mpjpe_mm(real, shifted) - 100.0 * 23 / 24) < 1e-2
    assert mpjpe_mm(real, shifted, root_relative=True) < 1e-3
