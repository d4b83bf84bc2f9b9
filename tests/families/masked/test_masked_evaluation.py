"""`t2m eval` for the masked family end to end: tiny joint VQ / masked / residual / length runs trained for a few
steps through the CLI on the tiny dataset, evaluated with the same command and evaluator as the GPT family; the
generation goes through the shared numpy loop, the reconstruction row is the joint VQ's, the stream rows are there."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from t2m.cli.main import main
from tests.model.synthetic_motion_data import make_dataset
from tests.model.test_evaluation import HashTextEncoder

TRAIN = ["--steps", "3", "--batch-size", "4", "--log-every", "1", "--val-every", "3", "--save-every", "3",
         "--threads", "1"]
TINY = ["--latent", "32", "--heads", "2", "--layers", "1", "--ff-size", "64", "--max-tokens", "20"]
ROWS = ("Real motion", "VQ reconstruction", "Generation (guidance=1)", "Generation (guidance=4)",
        "Generation, estimated lengths (guidance=1)", "Generation, estimated lengths (guidance=4)",
        "Streams (guidance=1)", "Streams (guidance=4)", "Real crops pasted (hard cuts)",
        "Real crops' VQ codes, decoded once")


@pytest.fixture(autouse=True)
def one_thread():
    torch.set_num_threads(1)


@pytest.fixture(scope="module")
def masked_runs(tmp_path_factory) -> dict[str, Path]:
    """The tiny dataset (its test split lists every clip), a random tiny evaluator, and the masked family's four runs
    trained for 3 steps (text features from the hashed stand-in of MiniLM, as at evaluation)."""
    from t2m.model.networks.evaluator import EvaluatorConfig, MotionEvaluator
    from t2m.model.training.checkpoint import save_checkpoint

    root = tmp_path_factory.mktemp("masked_eval")
    data = make_dataset(root / "data", train_clips=8, val_clips=3)
    ids = [line for split in ("train", "val", "test") for line in (data / f"{split}.txt").read_text().split()]
    (data / "test.txt").write_text("\n".join(ids) + "\n")
    runs = {name: root / name for name in ("joint_vq", "masked", "residual", "length", "evaluator", "vq1d",
                                           "masked1d", "residual1d")}
    runs["data"] = data
    torch.manual_seed(0)
    save_checkpoint(runs["evaluator"], MotionEvaluator(EvaluatorConfig(width=16, n_layer=1, n_head=2, embed_dim=8)), 0)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr("t2m.model.networks.text_encoders.get_text_encoder", lambda name, **kw: HashTextEncoder())
        text = ["--text-cache", str(root / "text_features.npz")]
        commands = [
            ["joint-vq", "--out", runs["joint_vq"], "--width", "8", "--code-dim", "8", "--nb-code", "16",
             "--residual-layers", "3"],
            ["masked", "--vq", runs["joint_vq"], "--out", runs["masked"], *TINY, *text],
            ["residual", "--vq", runs["joint_vq"], "--out", runs["residual"], "--codes-cache", runs["masked"], *TINY,
             *text],
            ["length", "--out", runs["length"], "--hidden", "16", *text],
            ["vq", "--out", runs["vq1d"], "--width", "16", "--code-dim", "8", "--nb-code", "16", "--quantizer",
             "residual", "--residual-layers", "2"],
            ["masked", "--vq", runs["vq1d"], "--out", runs["masked1d"], *TINY, *text],
            ["residual", "--vq", runs["vq1d"], "--out", runs["residual1d"], "--codes-cache", runs["masked1d"], *TINY,
             *text],
        ]
        for kind, *args in commands:
            assert main(["train", kind, "--data", str(data), *map(str, args), *TRAIN]) == 0, kind
    return runs


@pytest.fixture
def fast_text(monkeypatch):
    monkeypatch.setattr("t2m.model.networks.text_encoders.get_text_encoder", lambda name, **kw: HashTextEncoder())


@pytest.fixture
def loop_calls(monkeypatch) -> list[int]:
    """Segments per call of the shared numpy loop (t2m.families.masked.loop.sample_token_maps, as the PyTorch entry
    point
    imports it); the GPT sampler must not run at all."""
    import t2m.families.masked.sampling as masked_sampling

    calls: list[int] = []
    real = masked_sampling.sample_token_maps

    def counted(masked, residual, jobs, on_call=None):
        calls.append(sum(len(job.rows) for job in jobs))
        return real(masked, residual, jobs, on_call)

    def no_gpt(*args, **kwargs):
        raise AssertionError("the masked family must not sample with the GPT")

    monkeypatch.setattr(masked_sampling, "sample_token_maps", counted)
    monkeypatch.setattr("t2m.families.gpt.sampling.sample_codes", no_gpt)
    return calls


def _masked_args(runs: dict[str, Path], out: Path, *extra: str, vq: str = "joint_vq", masked: str = "masked",
                 residual: str = "residual") -> list[str]:
    return ["eval", "--data", str(runs["data"]), "--evaluator", str(runs["evaluator"]), "--vq", str(runs[vq]),
            "--masked", str(runs[masked]), "--residual", str(runs[residual]), "--limit", "10", "--repeats", "2",
            "--mm-texts", "3", "--mm-repeats", "2", "--steps", "3", "--out", str(out), "--quiet", *extra]


def test_masked_eval_writes_every_row_through_the_shared_loop(masked_runs, tmp_path, capsys, fast_text, loop_calls):
    out = tmp_path / "report.md"
    assert main(_masked_args(masked_runs, out, "--length", str(masked_runs["length"]))) == 0
    report = out.read_text()
    assert report in capsys.readouterr().out
    for row in ROWS:
        assert f"| {row} |" in report, row
    assert "nan" not in report.lower()
    assert "masked transformer `" in report and "3 re-masking steps" in report
    assert "residual stage guidance 5" in report and "Estimated lengths:" in report

    result = json.loads(out.with_suffix(".json").read_text())
    assert result["family"] == "masked" and result["options"]["guidance"] == [1.0, 4.0]
    assert result["decoding"] == {"steps": 3, "residual_guidance": 5.0, "residual_top_k": None,
                                  "residual_stage": True}
    assert set(result["models"]) == {"evaluator", "vq", "masked", "residual", "length"}
    for row, values in result["summary"].items():
        for key, (mean, half) in values.items():
            assert math.isfinite(mean) and math.isfinite(half) and half >= 0, (row, key)
    assert {"mpjpe_mm", "mpjpe_root_mm"} <= set(result["summary"]["recon"])
    for row in ("multi_g1", "multi_g4", "pasted", "pasted_codes"):
        assert {"sliding_fid", "transition_fid", "pelvis_jump_joins"} <= set(result["summary"][row]), row
    # 2 repeats x 2 guidance scales x (single sentences, MModality, estimated lengths, streams): one loop call each
    # (all rows fit one batch), with every clip / MModality row / stream segment as a segment of that call.
    clips, streams = result["counts"]["clips"], result["counts"]["streams_per_repeat"]
    assert loop_calls == [clips, 3 * 2, clips, 3 * streams] * 4


def test_reconstruction_row_is_the_joint_vqs_with_every_layer(masked_runs, fast_text):
    """The VQ reconstruction row's root-relative MPJPE equals the joint VQ's own encode -> decode of the same crops
    (all residual layers), computed here without the evaluation's helpers."""
    from t2m.families.masked.evaluation import MaskedSettings, load_masked_models
    from t2m.model.data.motion_data import MotionDirectory
    from t2m.model.evaluation.evaluate import (
        EvalOptions,
        draw,
        evaluate,
        mpjpe_mm,
        read_clips,
        reconstruct_codes,
    )
    from t2m.model.networks.joint_vqvae import JointVQVAE

    reader = MotionDirectory(masked_runs["data"], "test")
    models = load_masked_models(masked_runs["evaluator"], masked_runs["joint_vq"], masked_runs["masked"],
                                masked_runs["residual"], None, MaskedSettings(steps=2), reader.mean, reader.std)
    assert isinstance(models.vq, JointVQVAE)
    options = EvalOptions(repeats=1, limit=10, mm_texts=2, mm_repeats=2, guidance=(1.0,), multi_sentence=False,
                          progress=False)
    result = evaluate(models, reader, options)

    clips = read_clips(reader, options.limit)
    max_frames = min(models.evaluator.config.max_frames, 4 * models.family.max_tokens)
    reference = draw(clips, max_frames, np.random.default_rng(options.seed * 1000))
    mean, std = np.load(masked_runs["joint_vq"] / "mean.npy"), np.load(masked_runs["joint_vq"] / "std.npy")
    recon = []
    for motion in reference.motions:
        x = torch.from_numpy(((motion - mean) / std).astype(np.float32))[None]
        codes = models.vq.encode(x)
        assert codes.shape[2:] == (6, 3)
        with torch.no_grad():
            recon.append(models.vq.decode(codes)[0].numpy() * std + mean)
    assert result["repeats"][0]["recon"]["mpjpe_root_mm"] == pytest.approx(
        mpjpe_mm(reference.motions, recon, root_relative=True), rel=1e-5)
    assert all(c.shape[1:] == (6, 3) for c in reconstruct_codes(models, reference.motions[:2]))


def test_masked_eval_of_the_1d_variant(masked_runs, tmp_path, fast_text, loop_calls):
    """MoMask's 1D tokens: the maps' one column goes back to the 1D residual VQ's [T, R] codes."""
    out = tmp_path / "report.md"
    args = _masked_args(masked_runs, out, "--repeats", "1", "--guidance", "2", "--residual-guidance", "1",
                        vq="vq1d", masked="masked1d", residual="residual1d")
    assert main(args) == 0
    summary = json.loads(out.with_suffix(".json").read_text())["summary"]
    assert {"gen_g2", "multi_g2", "recon"} <= set(summary) and loop_calls
    assert all(math.isfinite(mean) for row in summary.values() for mean, _ in row.values())


def test_masked_eval_refuses_bad_input_with_exit_code_2(masked_runs, tmp_path, capsys, fast_text):
    out = str(tmp_path / "r.md")
    base = ["eval", "--data", str(masked_runs["data"]), "--evaluator", str(masked_runs["evaluator"]), "--out", out]
    joint, masked, residual = (str(masked_runs[k]) for k in ("joint_vq", "masked", "residual"))
    cases = [
        ([*base, "--vq", joint], "exactly one of --gpt RUN"),
        ([*base, "--vq", joint, "--masked", masked, "--gpt", masked], "exactly one of --gpt RUN"),
        ([*base, "--vq", joint, "--gpt", masked, "--residual", residual], "--residual applies to the masked family"),
        ([*base, "--vq", joint, "--masked", masked, "--steps", "0"], "--steps must be at least 1"),
        ([*base, "--vq", joint, "--masked", masked, "--residual-top-k", "0"], "--residual-top-k"),
        ([*base, "--vq", joint, "--masked", masked, "--residual", masked], "expected a residual checkpoint"),
        ([*base, "--vq", str(masked_runs["vq1d"]), "--masked", masked], "trained on the codes of"),
        ([*base, "--vq", joint, "--masked", str(masked_runs["masked1d"])], "trained on the codes of"),
    ]
    for argv, message in cases:
        assert main(argv) == 2, argv
        error = capsys.readouterr().err.strip()
        assert len(error.splitlines()) == 1 and message in error, (argv, error)


def test_stream_maps_are_generated_per_segment_concatenated_along_time_and_decoded_once(masked_runs, monkeypatch):
    """T2LM's streams as the service makes them: each segment's map for its own text and rows, the maps of a stream
    concatenated along time, one decode per stream."""
    import t2m.model.evaluation.evaluate as evaluation
    from t2m.families.masked.evaluation import MaskedSettings, load_masked_models
    from t2m.model.evaluation.evaluate import EvalOptions, multi_sentence

    reader_mean, reader_std = np.zeros(263, np.float32), np.ones(263, np.float32)
    models = load_masked_models(masked_runs["evaluator"], masked_runs["joint_vq"], masked_runs["masked"],
                                masked_runs["residual"], None, MaskedSettings(steps=2), reader_mean, reader_std)
    generated: dict[bytes, np.ndarray] = {}   # text feature -> its map (batches are sorted by length)
    decoded: list[list[np.ndarray]] = []
    real_codes, real_decode = models.family.codes, evaluation.decode

    def codes(cond_, *args, **kwargs):
        maps = real_codes(cond_, *args, **kwargs)
        generated.update((row.tobytes(), token_map) for row, token_map in zip(cond_, maps))
        return maps

    def decode(models_, codes_, batch_size=128):
        decoded.append([np.asarray(c) for c in codes_])
        return real_decode(models_, codes_, batch_size)

    monkeypatch.setattr(models.family, "codes", codes)
    monkeypatch.setattr(evaluation, "decode", decode)
    rng = np.random.default_rng(0)
    cond = rng.normal(size=(6, 384)).astype(np.float32)
    tokens = [3, 5, 2, 4, 4, 6]
    streams = np.array([[0, 1, 2], [3, 4, 5]])
    result = multi_sentence(models, cond, tokens, streams, 4.0, EvalOptions(progress=False, window=16, stride=8),
                            np.random.default_rng(1), real_window_emb=None)
    maps = [generated[row.tobytes()] for row in cond]
    assert [m.shape for m in maps] == [(t, 6, 3) for t in tokens]
    (stream_codes,) = decoded
    for stream, codes_ in zip(streams, stream_codes):
        np.testing.assert_array_equal(codes_, np.concatenate([maps[i] for i in stream]))
    assert math.isfinite(result["pelvis_jump_joins"])


def test_masked_batches_go_by_length_and_come_back_in_row_order(masked_runs, loop_calls):
    from t2m.families.masked.evaluation import MaskedSettings, load_masked_models
    from t2m.model.evaluation.evaluate import EvalOptions, sample

    models = load_masked_models(masked_runs["evaluator"], masked_runs["joint_vq"], masked_runs["masked"],
                                masked_runs["residual"], None, MaskedSettings(steps=2), np.zeros(263, np.float32),
                                np.ones(263, np.float32))
    cond = np.random.default_rng(0).normal(size=(3, 384)).astype(np.float32)
    maps = sample(models, cond, [5, 1, 2], 4.0, EvalOptions(batch_size=2, progress=False), np.random.default_rng(0),
                  "test")
    assert [m.shape[0] for m in maps] == [5, 1, 2]
    assert loop_calls == [2, 1]  # rows 1 and 2 (1 and 2 token rows) together, then row 0 alone
