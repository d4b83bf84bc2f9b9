"""Training pieces: corruption / dropout rates, LR schedule, datasets, checkpoints, resume, and 3-step CLI runs."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from t2m.families.gpt.network import GPTConfig, MotionGPT
from t2m.families.gpt.training import corrupt_codes, drop_length, sample_tau
from t2m.model.data.datasets import TextMotionDataset, VQWindowDataset, open_split, precompute_codes
from t2m.model.networks.vqvae import MotionVQVAE, VQConfig
from t2m.model.training.checkpoint import load_model, save_checkpoint
from t2m.model.training.conditioning import drop_condition, perturb_condition
from t2m.model.training.loop import LoopSettings, infinite, lr_factor, run_training

torch.set_num_threads(1)


# --- GPT training ingredients ----------------------------------------------------------------------------------


@pytest.mark.parametrize("tau", [0.2, 0.5])
def test_corruption_rate_is_close_to_tau_and_spares_end_and_pad(tau):
    generator = torch.Generator().manual_seed(0)
    tokens = torch.randint(0, 100, (200, 50), generator=generator)
    tokens[:, 40] = 100  # End
    tokens[:, 41:] = 101  # Pad
    corrupted = corrupt_codes(tokens, tau, codebook_size=100, generator=generator)
    codes = tokens < 100
    changed = (corrupted != tokens)[codes].float().mean().item()
    # a replaced code equals the original with probability 1/100
    assert changed == pytest.approx(tau * 0.99, abs=0.02)
    assert torch.equal(corrupted[~codes], tokens[~codes])
    assert int(corrupted[codes].max()) < 100


def test_uniform_corruption_draws_a_rate_per_row():
    taus = sample_tau(4000, "uniform", torch.Generator().manual_seed(0))
    assert taus.min() >= 0 and taus.max() <= 1 and taus.mean().item() == pytest.approx(0.5, abs=0.03)
    assert torch.equal(sample_tau(3, 0.25), torch.full((3,), 0.25))


def test_condition_dropout_rate_and_null_condition():
    cond = torch.randn(20000, 4) + 3.0
    dropped = drop_condition(cond, 0.1, torch.Generator().manual_seed(0))
    zero_rows = (dropped == 0).all(dim=1)
    assert zero_rows.float().mean().item() == pytest.approx(0.1, abs=0.01)
    assert torch.equal(dropped[~zero_rows], cond[~zero_rows])


def test_condition_noise_keeps_norms_and_bounds_the_cosine():
    """Noise of relative size s in D dims leaves a cosine of about 1/sqrt(1 + s^2) to the clean feature."""
    cond = torch.nn.functional.normalize(torch.randn(4000, 384), dim=-1) * 2.0
    cond[:10] = 0.0  # null conditions must stay null
    noisy = perturb_condition(cond, 0.8, torch.Generator().manual_seed(0))
    assert torch.equal(noisy[:10], cond[:10])
    assert torch.allclose(noisy[10:].norm(dim=-1), torch.full((3990,), 2.0), atol=1e-5)
    cosine = torch.nn.functional.cosine_similarity(noisy[10:], cond[10:], dim=-1)
    assert cosine.max() <= 1.0 + 1e-6 and cosine.min() >= 1 / (1 + 0.8**2) ** 0.5 - 0.1
    scales = torch.linspace(0, 0.8, 10001)
    assert cosine.mean().item() == pytest.approx((1 / (1 + scales**2).sqrt()).mean().item(), abs=0.01)
    assert torch.equal(perturb_condition(cond, 0.0), cond)


def test_length_dropout_keeps_the_true_length_with_the_given_probability():
    length = torch.full((20000,), 7)
    kept = drop_length(length, 0.8, torch.Generator().manual_seed(0))
    assert set(kept.unique().tolist()) == {0, 7}
    assert (kept == 7).float().mean().item() == pytest.approx(0.8, abs=0.01)


def test_lr_schedule_warms_up_then_steps_down():
    settings = LoopSettings(steps=100, warmup_steps=10, lr_milestones=(0.5, 0.8), lr_gamma=0.1)
    assert lr_factor(0, settings) == pytest.approx(0.1)
    assert lr_factor(9, settings) == pytest.approx(1.0)
    assert lr_factor(49, settings) == 1.0
    assert lr_factor(50, settings) == pytest.approx(0.1)
    assert lr_factor(80, settings) == pytest.approx(0.01)


# --- datasets ---------------------------------------------------------------------------------------------------


def test_vq_windows_are_normalised_crops_and_short_clips_are_left_out(data_dir):
    reader = open_split(data_dir, "train")
    dataset = VQWindowDataset(reader, window=64)
    assert "train000" not in dataset.ids and len(dataset) == len(reader.ids) - 1  # train000 has 40 frames
    window = dataset[0]
    assert window.shape == (64, 263) and window.dtype == torch.float32
    raw = (reader.features(dataset.ids[0]) - reader.mean) / reader.std
    starts = [s for s in range(len(raw) - 63) if np.allclose(raw[s : s + 64], window.numpy(), atol=1e-6)]
    assert starts, "the window is not a crop of the normalised clip"
    fixed = VQWindowDataset(open_split(data_dir, "val"), window=64, fixed_offsets=True)
    assert torch.equal(fixed[0], fixed[0])


def test_text_motion_items_pad_with_end_and_pad_and_crop_long_clips(data_dir):
    reader = open_split(data_dir, "train")
    codes = {clip_id: np.arange(len(reader.features(clip_id)) // 4) % 10 for clip_id in reader.ids}
    captions = {c for i in reader.ids for c in reader.captions(i)}
    features = {c: np.full(384, i, np.float32) for i, c in enumerate(captions)}
    dataset = TextMotionDataset(reader, codes, features, codebook_size=10, max_tokens=20)
    short = dataset.ids.index("train000")  # 40 frames -> 10 codes
    item = dataset[short]
    assert item["length"].item() == 10
    tokens = item["tokens"]
    assert tokens.shape == (21,)
    assert tokens[:10].tolist() == list(range(10)) and tokens[10] == 10 and (tokens[11:] == 11).all()
    assert item["cond"].shape == (384,)
    long = dataset.ids.index("train001")  # 170 frames -> 42 codes > 20
    item = dataset[long]
    assert item["length"].item() == 20 and (item["tokens"][:20] < 10).all() and item["tokens"][20] == 11


def test_precomputed_codes_have_one_code_per_four_frames(data_dir):
    reader = open_split(data_dir, "val")
    vq = MotionVQVAE(VQConfig(width=16, code_dim=8, nb_code=16))
    codes = precompute_codes(vq, reader)
    for clip_id in reader.ids:
        assert codes[clip_id].shape == (len(reader.features(clip_id)) // 4,)
        assert codes[clip_id].dtype == np.int64


# --- checkpoints and resume -----------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["vq", "gpt"])
def test_checkpoint_round_trip(tmp_path, kind):
    torch.manual_seed(0)
    if kind == "vq":
        model = MotionVQVAE(VQConfig(width=16, code_dim=8, nb_code=16, quantizer="residual", residual_layers=2))
        x = torch.randn(1, 16, 263)
        run = lambda m: m.eval()(x)[0]  # noqa: E731
    else:
        model = MotionGPT(GPTConfig(codebook_size=16, embed=32, n_head=4, n_layer_base=1, n_layer_head=1,
                                    block_size=9, text_dim=8))
        cond, tokens = torch.randn(2, 8), torch.randint(0, 16, (2, 5))
        run = lambda m: m.eval()(cond, tokens, torch.tensor([3, 0]))  # noqa: E731
    save_checkpoint(tmp_path, model, step=7, data={"note": "test"})
    record = json.loads((tmp_path / "config.json").read_text())
    assert record["kind"] == kind and record["step"] == 7 and record["data"] == {"note": "test"}
    loaded = load_model(tmp_path)
    assert type(loaded) is type(model) and loaded.config == model.config
    torch.testing.assert_close(run(loaded), run(model))
    with pytest.raises(ValueError, match="expected a"):
        load_model(tmp_path, expect_kind="evaluator")


def test_load_model_names_the_bad_file(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_model(tmp_path)
    (tmp_path / "config.json").write_text('{"kind": "banana", "config": {}}')
    with pytest.raises(ValueError, match="kind"):
        load_model(tmp_path)


def _tiny_vq_run(run_dir: Path, steps: int, resume: bool) -> MotionVQVAE:
    torch.manual_seed(0)
    model = MotionVQVAE(VQConfig(width=16, code_dim=8, nb_code=16))
    windows = torch.randn(8, 16, 263)
    loader = torch.utils.data.DataLoader(windows, batch_size=4, shuffle=True)

    def step_fn(net, batch):
        recon, parts = net(batch)
        loss = torch.nn.functional.smooth_l1_loss(recon, batch) + 0.02 * parts["commit"]
        return loss, {"commit": float(parts["commit"].detach())}, len(batch)

    settings = LoopSettings(steps=steps, warmup_steps=2, log_every=1, val_every=2, save_every=3)
    run_training(model, infinite(loader), step_fn, settings, run_dir, val_fn=lambda net: {"dummy": 1.0},
                 resume=resume, name="test")
    return model


def test_resume_continues_from_the_saved_step(tmp_path):
    first = _tiny_vq_run(tmp_path, steps=3, resume=False)
    assert json.loads((tmp_path / "config.json").read_text())["step"] == 3
    ema_count = first.quantizer.code_count.clone()
    assert ema_count.sum() > 0
    resumed = _tiny_vq_run(tmp_path, steps=5, resume=True)
    assert json.loads((tmp_path / "config.json").read_text())["step"] == 5
    with (tmp_path / "log.csv").open() as handle:
        steps = [int(row["step"]) for row in csv.DictReader(handle)]
    assert steps == [1, 2, 3, 4, 5]
    assert "resuming at step 3" in (tmp_path / "train.log").read_text()
    assert (tmp_path / "curves.png").stat().st_size > 1000
    assert bool(resumed.quantizer.initialized)  # EMA state came back from resume.pt, no re-init from a batch


# --- the CLI ----------------------------------------------------------------------------------------------------


def test_cli_trains_vq_then_gpt_for_three_steps(data_dir, tmp_path, monkeypatch):
    from t2m.cli.main import main

    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    vq_run, gpt_run = tmp_path / "vq", tmp_path / "gpt"
    common = ["--steps", "3", "--batch-size", "4", "--log-every", "1", "--val-every", "3", "--save-every", "3",
              "--threads", "1"]
    assert main(["train", "vq", "--data", str(data_dir), "--out", str(vq_run), "--width", "16", "--code-dim", "8",
                 "--nb-code", "16", *common]) == 0
    vq = load_model(vq_run, expect_kind="vq")
    assert vq.config.width == 16 and (vq_run / "mean.npy").is_file()
    with (vq_run / "log.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert [r["step"] for r in rows] == ["1", "2", "3"] and float(rows[-1]["samples_per_s"]) > 0
    assert rows[-1]["val_mpjpe_mm"] != ""
    # a second run into the same directory without --resume is refused with a clear message
    assert main(["train", "vq", "--data", str(data_dir), "--out", str(vq_run), *common]) == 2

    assert main(["train", "gpt", "--data", str(data_dir), "--vq", str(vq_run), "--out", str(gpt_run),
                 "--embed", "32", "--layers", "2", "--heads", "2", "--max-tokens", "20", *common]) == 0
    gpt = load_model(gpt_run, expect_kind="gpt")
    assert gpt.config.codebook_size == 16 and gpt.config.text_dim == 384 and gpt.config.block_size == 21
    record = json.loads((gpt_run / "config.json").read_text())
    assert record["data"]["text_encoder"]["kind"] == "minilm" and record["data"]["vq_run"] == str(vq_run.resolve())
    assert (gpt_run / "text_features.npz").is_file() and (gpt_run / "codes_train.npz").is_file()


def test_cli_balanced_sampling_is_recorded(data_dir, tmp_path, monkeypatch):
    """--balance-power < 1 trains both stages with action-balanced draws and records the masses it used (and the
    GPT its --cond-noise); out-of-range values are refused with exit code 2."""
    from t2m.cli.main import main

    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    vq_run, gpt_run = tmp_path / "vq", tmp_path / "gpt"
    common = ["--steps", "2", "--batch-size", "4", "--log-every", "1", "--val-every", "2", "--save-every", "2",
              "--threads", "1", "--balance-power", "0.3"]
    assert main(["train", "vq", "--data", str(data_dir), "--out", str(vq_run), "--width", "16", "--code-dim", "8",
                 "--nb-code", "16", *common]) == 0
    assert main(["train", "gpt", "--data", str(data_dir), "--vq", str(vq_run), "--out", str(gpt_run),
                 "--embed", "32", "--layers", "2", "--heads", "2", "--max-tokens", "20", "--cond-noise", "0.4",
                 *common]) == 0
    for run in (vq_run, gpt_run):
        masses = json.loads((run / "action_masses.json").read_text())
        assert masses and sum(masses.values()) == pytest.approx(1.0)
    assert json.loads((vq_run / "config.json").read_text())["data"]["balance_power"] == 0.3
    gpt_training = json.loads((gpt_run / "config.json").read_text())["data"]["training"]
    assert gpt_training["balance_power"] == 0.3 and gpt_training["cond_noise"] == 0.4
    bad = ["--steps", "1", "--threads", "1", "--balance-power", "1.5"]
    assert main(["train", "gpt", "--data", str(data_dir), "--vq", str(vq_run), "--out", str(tmp_path / "noisy_gpt"),
                 "--steps", "1", "--threads", "1", "--cond-noise", "-0.5"]) == 2
    assert main(["train", "vq", "--data", str(data_dir), "--out", str(tmp_path / "bad_vq"), *bad]) == 2
    assert main(["train", "gpt", "--data", str(data_dir), "--vq", str(vq_run), "--out", str(tmp_path / "bad_gpt"),
                 *bad]) == 2


def test_cli_records_the_bone_weight_and_refuses_a_negative_one(data_dir, tmp_path):
    """--bone-weight reaches the loss (its part is logged), is recorded, and a negative weight is refused."""
    from t2m.cli.main import main

    run = tmp_path / "vq"
    assert main(["train", "vq", "--data", str(data_dir), "--out", str(run), "--width", "16", "--code-dim", "8",
                 "--nb-code", "16", "--steps", "2", "--batch-size", "4", "--log-every", "1", "--val-every", "2",
                 "--save-every", "2", "--threads", "1", "--bone-weight", "0.5"]) == 0
    config = json.loads((run / "config.json").read_text())
    assert config["data"]["loss"]["bone_weight"] == 0.5
    log = (run / "log.csv").read_text()
    assert "bone_m" in log.splitlines()[0] and "bone_std_mm" in log
    assert main(["train", "vq", "--data", str(data_dir), "--out", str(tmp_path / "bad"), "--steps", "1",
                 "--threads", "1", "--bone-weight", "-1"]) == 2
