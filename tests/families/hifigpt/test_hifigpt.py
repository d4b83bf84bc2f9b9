"""T2M-HiFiGPT's double-tier GPT: shapes, the step methods against the whole-sequence pass, the VQ's codebooks as its
inputs, per-time-step corruption, the losses, the reference sampler (targets, stop, seeds) and `t2m train hifigpt`
(a few steps on a tiny dataset, resume, refusals)."""
from __future__ import annotations

import csv
import json

import numpy as np
import pytest
import torch

from t2m.cli.main import main
from t2m.families.hifigpt.network import HiFiGPT, HiFiGPTConfig, vq_codebooks, vq_fields
from t2m.families.hifigpt.sampling import sample_code_maps
from t2m.families.hifigpt.training import corrupt_steps, hifigpt_loss
from t2m.model.networks.vqvae import MotionVQVAE, VQConfig
from t2m.model.training.checkpoint import load_model, save_checkpoint

torch.set_num_threads(1)


def tiny(**overrides) -> HiFiGPT:
    torch.manual_seed(0)
    settings = {"codebook_size": 16, "depth": 3, "code_dim": 8, "embed": 16, "n_head": 2, "n_layer_temporal": 2,
                "n_layer_residual": 1, "max_tokens": 8, "text_dim": 12, "dropout": 0.0}
    return HiFiGPT(HiFiGPTConfig(**{**settings, **overrides})).eval()


@pytest.mark.parametrize("shared", [False, True])
def test_step_methods_give_the_whole_sequence_logits(shared):
    model = tiny(shared_codebook=shared)
    cond, codes, length = torch.randn(2, 12), torch.randint(0, 16, (2, 6, 3)), torch.tensor([6, 0])
    with torch.no_grad():
        logits, stop = model(cond, codes, length)
        assert logits.shape == (2, 6, 3, 16) and stop.shape == (2, 7)
        past = model.empty_cache("temporal", 2)
        for p in range(7):
            previous = codes[:, p - 1] if p else torch.zeros(2, 3, dtype=torch.long)
            context, stop_p, past = model.temporal_step(cond, previous, p, length, past)
            torch.testing.assert_close(stop_p, stop[:, p], atol=1e-5, rtol=0)
            if p == 6:
                break
            inner = model.empty_cache("residual", 2)
            for d in range(3):
                code = codes[:, p, d - 1] if d else torch.zeros(2, dtype=torch.long)
                step_logits, inner = model.residual_step(context, code, d, inner)
                torch.testing.assert_close(step_logits, logits[:, p, d], atol=1e-5, rtol=0)
        assert past.shape == (2, 2, 2, 2, 7, 8) and inner.shape == (1, 2, 2, 2, 3, 8)


def test_the_temporal_input_is_the_quantised_latent_of_the_vq():
    """The GPT reads the VQ's own codebooks: a step's input is (projected) the latent the decoder sums."""
    torch.manual_seed(0)
    vq = MotionVQVAE(VQConfig(width=8, code_dim=8, nb_code=16, down_t=3, depth=1, quantizer="residual",
                              residual_layers=3)).eval()
    fields = vq_fields(vq.config.to_dict())
    assert fields == {"codebook_size": 16, "code_dim": 8, "depth": 3, "shared_codebook": False}
    model = tiny(**fields)
    model.set_codebooks(vq_codebooks(vq))
    codes = torch.randint(0, 16, (2, 5, 3))
    codes[0, :, 2] = -1   # an unused depth contributes nothing, as in the decoder
    torch.testing.assert_close(model.latent(codes), vq.quantizer.codes_to_latent(codes))
    with pytest.raises(ValueError, match=r"codebooks must be \[3, 16, 8\]"):
        model.set_codebooks(torch.zeros(1, 16, 8))


def test_corruption_replaces_whole_time_steps():
    generator = torch.Generator().manual_seed(0)
    codes = torch.randint(0, 1000, (64, 20, 6), generator=generator)
    codes[:, 15:] = -1                                   # padding past the motions' end
    corrupted, replaced = corrupt_steps(codes, 0.5, 1000, generator)
    same = (corrupted == codes).all(dim=-1)
    changed = (corrupted != codes).sum(dim=-1)
    assert torch.equal(same, ~replaced)                  # a kept step is kept whole
    assert (changed[replaced] >= 5).all()                # a replaced one is a new row (a code may repeat by chance)
    assert not replaced[:, 15:].any() and (corrupted[:, 15:] == -1).all()
    assert 0.45 < replaced[:, :15].float().mean() < 0.55
    _, replaced = corrupt_steps(codes, torch.tensor([0.0, 1.0] * 32), 1000, generator)
    assert not replaced[0::2].any() and replaced[1::2, :15].all()


def test_loss_trains_codes_and_stop_where_a_window_ends():
    model = tiny().train()
    batch = {"codes": torch.randint(0, 16, (3, 8, 1, 3)), "length": torch.tensor([8, 5, 3]),
             "ends": torch.tensor([True, False, True])}
    batch["codes"][1, 5:] = -1
    batch["codes"][2, 3:] = -1
    loss, metrics = hifigpt_loss(model, batch, torch.randn(3, 12), tau=0.5, length_keep=0.5)
    loss.backward()
    assert set(metrics) == {"ce", "acc", "acc_d0", "stop_bce", "stop_acc"} and np.isfinite(loss.item())
    assert model.head.weight.grad.abs().sum() > 0 and model.stop_head.weight.grad.abs().sum() > 0
    assert model.codebooks.grad is None                  # the VQ's codebooks stay as they are


def test_reference_sampler_targets_free_lengths_and_seeds():
    model = tiny()
    cond = torch.randn(3, 12)
    maps = sample_code_maps(model, cond, [4, None, 8], guidance=2.0, top_k=5, rng=1)
    assert maps[0].shape == (4, 3) and maps[2].shape == (8, 3)
    assert 1 <= len(maps[1]) <= 8 and all((m >= 0).all() and (m < 16).all() for m in maps)
    again = sample_code_maps(model, cond, [4, None, 8], guidance=2.0, top_k=5, rng=1)
    assert all(np.array_equal(a, b) for a, b in zip(maps, again))
    greedy = sample_code_maps(model, cond[[0, 0]], [5, 5], temperature=0)   # argmax: the same text, the same map
    assert np.array_equal(greedy[0], greedy[1])
    with pytest.raises(ValueError, match=r"segment 0: target of 9 tokens is outside 1..8"):
        sample_code_maps(model, cond[:1], [9])


COMMON = ["--steps", "3", "--batch-size", "4", "--log-every", "1", "--val-every", "3", "--save-every", "3",
          "--threads", "1"]


@pytest.fixture(autouse=True)
def offline(monkeypatch):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")


def test_cli_trains_a_residual_vq_at_8_frames_and_the_double_tier_gpt(data_dir, tmp_path):
    vq_run, run = tmp_path / "vq", tmp_path / "hifigpt"
    assert main(["train", "vq", "--data", str(data_dir), "--out", str(vq_run), "--width", "8", "--code-dim", "8",
                 "--nb-code", "16", "--down-t", "3", "--window", "32", "--quantizer", "residual",
                 "--residual-layers", "3", "--shared-codebook", "--depth", "1", *COMMON]) == 0
    vq = load_model(vq_run, expect_kind="vq")
    assert vq.frames_per_token == 8 and vq.config.shared_codebook
    tiny_gpt = ["--embed", "16", "--heads", "2", "--temporal-layers", "1", "--residual-gpt-layers", "1",
                "--max-tokens", "10"]
    assert main(["train", "hifigpt", "--data", str(data_dir), "--vq", str(vq_run), "--out", str(run), *tiny_gpt,
                 *COMMON]) == 0
    model = load_model(run, expect_kind="hifigpt")
    assert isinstance(model, HiFiGPT)
    assert (model.config.depth, model.config.codebook_size, model.config.shared_codebook) == (3, 16, True)
    torch.testing.assert_close(model.codebooks, vq_codebooks(vq))
    record = json.loads((run / "config.json").read_text())
    assert record["data"]["frames_per_token"] == 8 and record["data"]["vq_run"] == str(vq_run.resolve())
    assert record["data"]["training"]["corruption"] == 0.5 and record["data"]["training"]["cond_drop"] == 0.1
    with (run / "log.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert [r["step"] for r in rows] == ["1", "2", "3"] and rows[-1]["val_stop_bce"] != ""
    assert (run / "curves.png").is_file()
    # resume continues the same run; a second run into it is refused
    assert main(["train", "hifigpt", "--data", str(data_dir), "--vq", str(vq_run), "--out", str(run), *tiny_gpt,
                 *COMMON[:1], "5", *COMMON[2:], "--resume"]) == 0
    assert json.loads((run / "config.json").read_text())["step"] == 5
    assert main(["train", "hifigpt", "--data", str(data_dir), "--vq", str(vq_run), "--out", str(run),
                 *tiny_gpt, *COMMON]) == 2


def test_cli_refuses_a_vq_of_another_kind(data_dir, tmp_path, capsys):
    save_checkpoint(tmp_path / "gpt", tiny(), 0)
    (tmp_path / "gpt" / "config.json").write_text(json.dumps({"kind": "gpt", "config": {}}))
    assert main(["train", "hifigpt", "--data", str(data_dir), "--vq", str(tmp_path / "gpt"),
                 "--out", str(tmp_path / "out"), *COMMON]) == 2
    assert "--vq must be a vq run" in capsys.readouterr().err
