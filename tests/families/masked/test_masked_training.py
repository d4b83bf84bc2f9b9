"""Training the masked family: `t2m train joint-vq|masked|residual|length` for a few steps on a tiny dataset (2D and
MoMask's 1D tokens), checkpoints of every kind, resume, condition dropout and the refusals of bad input."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
import torch

from t2m.cli.main import main
from t2m.families.masked.length_estimator import LengthEstimator, LengthEstimatorConfig
from t2m.families.masked.masked_transformer import MaskedTransformer
from t2m.families.masked.residual_transformer import ResidualTransformer
from t2m.model.networks.joint_vqvae import JointVQConfig, JointVQVAE
from t2m.model.networks.token_transformer import TokenTransformerConfig
from t2m.model.training.checkpoint import load_model, save_checkpoint
from t2m.model.training.token_models import noisy_condition

torch.set_num_threads(1)

COMMON = ["--steps", "3", "--batch-size", "4", "--log-every", "1", "--val-every", "3", "--save-every", "3",
          "--threads", "1"]
TINY = ["--latent", "32", "--heads", "2", "--layers", "1", "--ff-size", "64", "--max-tokens", "20"]


@pytest.fixture(scope="module")
def joint_vq_run(data_dir, tmp_path_factory) -> Path:
    run = tmp_path_factory.mktemp("runs") / "joint_vq"
    assert main(["train", "joint-vq", "--data", str(data_dir), "--out", str(run), "--width", "8", "--code-dim", "8",
                 "--nb-code", "16", "--residual-layers", "3", *COMMON]) == 0
    return run


def log_rows(run: Path) -> list[dict[str, str]]:
    with (run / "log.csv").open() as handle:
        return list(csv.DictReader(handle))


@pytest.fixture(autouse=True)
def offline(monkeypatch):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")


def test_cli_trains_the_joint_vq(joint_vq_run):
    vq = load_model(joint_vq_run, expect_kind="joint_vq")
    assert isinstance(vq, JointVQVAE) and vq.config.residual_layers == 3 and vq.config.columns == 6
    rows = log_rows(joint_vq_run)
    assert [r["step"] for r in rows] == ["1", "2", "3"] and float(rows[-1]["samples_per_s"]) > 0
    assert rows[-1]["val_mpjpe_mm"] != "" and rows[-1]["val_perplexity"] != ""
    record = json.loads((joint_vq_run / "config.json").read_text())
    assert record["data"]["columns"] == 6 and record["data"]["frames_per_token"] == 4
    assert (joint_vq_run / "mean.npy").is_file() and (joint_vq_run / "curves.png").is_file()


def test_cli_trains_masked_residual_and_length_on_the_joint_vq(data_dir, joint_vq_run, tmp_path):
    masked_run, residual_run, length_run = tmp_path / "masked", tmp_path / "residual", tmp_path / "length"
    assert main(["train", "masked", "--data", str(data_dir), "--vq", str(joint_vq_run), "--out", str(masked_run),
                 *TINY, *COMMON]) == 0
    masked = load_model(masked_run, expect_kind="masked")
    assert isinstance(masked, MaskedTransformer)
    assert masked.config.columns == 6 and masked.config.positional == "2d" and masked.config.codebook_size == 16
    assert masked.config.spatial_attention and masked.config.temporal_attention and masked.config.text_dim == 384
    record = json.loads((masked_run / "config.json").read_text())
    assert record["data"]["vq_run"] == str(joint_vq_run.resolve()) and record["data"]["vq_kind"] == "joint_vq"
    assert record["data"]["text_encoder"]["kind"] == "minilm" and record["data"]["training"]["cond_drop"] == 0.1
    rows = log_rows(masked_run)
    assert [r["step"] for r in rows] == ["1", "2", "3"] and rows[-1]["val_ce_all_masked"] != ""

    stamp = (masked_run / "codes_train.json").stat().st_mtime_ns
    assert main(["train", "residual", "--data", str(data_dir), "--vq", str(joint_vq_run), "--out", str(residual_run),
                 "--codes-cache", str(masked_run), "--text-cache", str(masked_run / "text_features.npz"),
                 *TINY, *COMMON]) == 0
    assert (masked_run / "codes_train.json").stat().st_mtime_ns == stamp  # the same VQ's codes were reused
    residual = load_model(residual_run, expect_kind="residual")
    assert isinstance(residual, ResidualTransformer) and residual.config.residual_layers == 3
    assert json.loads((residual_run / "config.json").read_text())["data"]["training"]["cond_drop"] == 0.2
    assert "val_ce" in log_rows(residual_run)[-1]

    assert main(["train", "length", "--data", str(data_dir), "--out", str(length_run), "--hidden", "16",
                 "--text-cache", str(masked_run / "text_features.npz"), *COMMON]) == 0
    estimator = load_model(length_run, expect_kind="length")
    assert isinstance(estimator, LengthEstimator) and estimator.config.max_tokens == 50
    assert log_rows(length_run)[-1]["val_mae_rows"] != ""


def test_cli_trains_the_1d_variant_on_a_residual_1d_vq(data_dir, joint_vq_run, tmp_path):
    vq_run, masked_run, residual_run = tmp_path / "vq", tmp_path / "masked", tmp_path / "residual"
    assert main(["train", "vq", "--data", str(data_dir), "--out", str(vq_run), "--width", "16", "--code-dim", "8",
                 "--nb-code", "16", "--quantizer", "residual", "--residual-layers", "2", *COMMON]) == 0
    # a codes cache made by another VQ (the joint one) is not reused: its stamp names that VQ
    shared_cache = tmp_path / "codes"
    for run, kind in ((masked_run, "masked"), (residual_run, "residual")):
        assert main(["train", kind, "--data", str(data_dir), "--vq", str(vq_run), "--out", str(run),
                     "--codes-cache", str(shared_cache), *TINY, *COMMON]) == 0
        model = load_model(run, expect_kind=kind)
        assert model.config.columns == 1 and model.config.positional == "1d"
        assert not model.config.spatial_attention and not model.config.temporal_attention
        assert "position_enc.pe" in model.state_dict()
    assert json.loads((shared_cache / "codes_train.json").read_text())["vq_run"] == str(vq_run.resolve())


def test_masked_training_resumes_from_the_saved_step(data_dir, joint_vq_run, tmp_path):
    run = tmp_path / "masked"
    args = ["train", "masked", "--data", str(data_dir), "--vq", str(joint_vq_run), "--out", str(run), *TINY,
            "--batch-size", "4", "--log-every", "1", "--val-every", "2", "--save-every", "2", "--threads", "1"]
    assert main([*args, "--steps", "2"]) == 0
    assert main([*args, "--steps", "4", "--resume"]) == 0
    assert [r["step"] for r in log_rows(run)] == ["1", "2", "3", "4"]
    assert json.loads((run / "config.json").read_text())["step"] == 4
    assert "resuming at step 2" in (run / "train.log").read_text()


def test_cli_refuses_bad_input_with_exit_code_2(data_dir, joint_vq_run, tmp_path, capsys):
    plain_vq = tmp_path / "plain_vq"
    assert main(["train", "vq", "--data", str(data_dir), "--out", str(plain_vq), "--width", "8", "--code-dim", "8",
                 "--nb-code", "16", *COMMON]) == 0
    capsys.readouterr()
    cases = [
        (["train", "joint-vq", "--data", str(data_dir), "--out", str(tmp_path / "a"), "--down-j", "3"], "down_j"),
        (["train", "joint-vq", "--data", str(data_dir), "--out", str(joint_vq_run)], "already holds a run"),
        (["train", "residual", "--data", str(data_dir), "--vq", str(plain_vq), "--out", str(tmp_path / "b"), *TINY],
         "at least 2"),
        (["train", "masked", "--data", str(data_dir), "--vq", str(tmp_path / "missing"), "--out", str(tmp_path / "c")],
         "file not found"),
        (["train", "masked", "--data", str(data_dir), "--vq", str(joint_vq_run), "--out", str(tmp_path / "d"),
          "--cond-drop", "1.5"], "--cond-drop"),
        (["train", "length", "--data", str(data_dir), "--out", str(tmp_path / "e"), "--hidden", "0"], "--hidden"),
    ]
    for argv, message in cases:
        assert main([*argv, "--steps", "1", "--threads", "1"]) == 2, argv
        error = capsys.readouterr().err.strip()
        assert len(error.splitlines()) == 1 and message in error, error


def test_condition_dropout_zeroes_the_text_feature_at_the_given_rate():
    class Args:
        cond_drop, cond_noise = 0.2, 0.0

    cond = torch.randn(20000, 8) + 3.0
    dropped = noisy_condition(cond, Args, torch.Generator().manual_seed(0))
    null = (dropped == 0).all(dim=1)
    assert null.float().mean().item() == pytest.approx(0.2, abs=0.01)
    assert torch.equal(dropped[~null], cond[~null])


@pytest.mark.parametrize("kind", ["joint_vq", "masked", "residual", "length"])
def test_checkpoint_round_trip_of_every_kind(tmp_path, kind):
    torch.manual_seed(0)
    tiny = TokenTransformerConfig(codebook_size=16, columns=6, residual_layers=3, max_tokens=8, latent=32, n_head=2,
                                  n_layer=1, ff_size=64, text_dim=8, code_dim=16)
    cond, length = torch.randn(2, 8), torch.tensor([5, 3])
    if kind == "joint_vq":
        model = JointVQVAE(JointVQConfig(width=8, code_dim=8, nb_code=16, residual_layers=2))
        x = torch.randn(1, 16, 263)
        run = lambda m: m(x)[0]  # noqa: E731
    elif kind == "masked":
        model = MaskedTransformer(tiny)
        tokens = torch.randint(0, 16, (2, 5, 6))
        run = lambda m: m(tokens, cond, length)  # noqa: E731
    elif kind == "residual":
        model = ResidualTransformer(tiny)
        codes = torch.randint(0, 16, (2, 5, 6, 3))
        run = lambda m: m(codes, torch.tensor([1, 2]), cond, length)  # noqa: E731
    else:
        model = LengthEstimator(LengthEstimatorConfig(text_dim=8, hidden=16, max_tokens=8))
        run = lambda m: m(cond)  # noqa: E731
    save_checkpoint(tmp_path, model, step=5)
    assert json.loads((tmp_path / "config.json").read_text())["kind"] == kind
    loaded = load_model(tmp_path, expect_kind=kind)
    assert type(loaded) is type(model) and loaded.config == model.config
    torch.testing.assert_close(run(loaded), run(model.eval()))
