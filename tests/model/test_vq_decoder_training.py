"""`t2m train vq-decoder`: a new decoder on a trained VQ's frozen codes (the default's short-lookahead decoder).

Causal residual blocks read no frame ahead; the new decoder starts from the old one with its taps moved into the
past; training changes the decoder alone (encoder, codebooks and EMA statistics stay bit for bit, so the codes the
text-to-code model learnt are the ones it decodes); bad options are refused naming the option."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from t2m.model.networks.vqvae import MotionVQVAE, ResBlock, VQConfig
from t2m.model.training.checkpoint import load_model
from t2m.model.training.train_vq_decoder import move_taps_into_the_past

torch.set_num_threads(1)

TINY = ["--width", "16", "--code-dim", "8", "--nb-code", "16", "--quantizer", "residual", "--residual-layers", "2"]
FEW_STEPS = ["--steps", "3", "--batch-size", "4", "--log-every", "1", "--val-every", "3", "--save-every", "3",
             "--threads", "1"]


@pytest.fixture(scope="module")
def vq_run(data_dir, tmp_path_factory) -> Path:
    from t2m.cli.main import main

    run = tmp_path_factory.mktemp("runs") / "rvq"
    assert main(["train", "vq", "--data", str(data_dir), "--out", str(run), *TINY, *FEW_STEPS]) == 0
    return run


@pytest.mark.parametrize("causal", [False, True])
def test_a_causal_block_reads_no_frame_ahead(causal):
    torch.manual_seed(0)
    block = ResBlock(width=4, dilation=3, causal=causal).eval()
    x = torch.randn(1, 4, 40)
    changed = x.clone()
    changed[..., 20] += 1.0
    moved = (block(changed) - block(x)).abs().sum(dim=1)[0].nonzero().flatten()
    assert moved.min() == (20 if causal else 17) and moved.max() == (26 if causal else 23)


def test_the_new_decoder_starts_from_the_old_one_with_its_taps_moved_into_the_past():
    torch.manual_seed(0)
    source = MotionVQVAE(VQConfig(width=8, code_dim=8, nb_code=16, depth=2))
    target = MotionVQVAE(VQConfig(width=8, code_dim=8, nb_code=16, depth=2, causal_decoder_blocks=True))
    move_taps_into_the_past(source, target)
    old, new = source.state_dict(), target.state_dict()
    moved = [name for name in old if not torch.equal(old[name], new[name])]
    assert moved and all(name.startswith("decoder.") and name.endswith("conv1.weight") for name in moved)
    for name in moved:
        assert torch.equal(new[name][..., 1:], old[name][..., :2]) and not new[name][..., 0].any()


@pytest.fixture(scope="module")
def decoder_run(data_dir, vq_run, tmp_path_factory) -> Path:
    from t2m.cli.main import main

    out = tmp_path_factory.mktemp("runs") / "causal"
    assert main(["train", "vq-decoder", "--data", str(data_dir), "--vq", str(vq_run), "--out", str(out),
                 *FEW_STEPS]) == 0
    return out


def test_training_changes_the_decoder_alone(vq_run, decoder_run):
    out = decoder_run
    source, trained = load_model(vq_run, "vq"), load_model(out, "vq")
    assert trained.config.causal_decoder_blocks and not source.config.causal_decoder_blocks
    assert (out / "mean.npy").read_bytes() == (vq_run / "mean.npy").read_bytes()
    old, new = source.state_dict(), trained.state_dict()
    assert all(torch.equal(old[name], new[name]) for name in old if not name.startswith("decoder."))
    # conv1 kernels were moved, so compare the rest of the decoder: it learnt
    assert any(not torch.equal(old[name], new[name]) for name in old
               if name.startswith("decoder.") and "conv1" not in name)
    assert "val_mpjpe_mm" in (out / "log.csv").read_text().splitlines()[0]


def test_bad_options_are_refused(data_dir, vq_run, tmp_path):
    from t2m.cli.main import main

    common = ["--data", str(data_dir), "--vq", str(vq_run), "--steps", "1", "--threads", "1"]
    assert main(["train", "vq-decoder", *common, "--out", str(vq_run)]) == 2            # would overwrite the source
    assert main(["train", "vq-decoder", *common, "--out", str(tmp_path / "a"), "--window", "30"]) == 2  # not x4
    assert main(["train", "vq-decoder", *common, "--out", str(tmp_path / "b"), "--bone-weight", "-1"]) == 2
    assert main(["train", "vq-decoder", "--data", str(data_dir), "--vq", str(tmp_path / "none"),
                 "--out", str(tmp_path / "c")]) == 2


def test_a_token_model_of_the_old_codes_is_accepted_with_the_new_decoder_and_another_vq_is_refused(
        data_dir, vq_run, decoder_run, tmp_path):
    """`t2m eval` and the exporters check that a GPT / HiFiGPT / masked run learnt the --vq's codes: a new decoder on
    the same codes gives them, an independently trained VQ does not."""
    from t2m.cli.main import main
    from t2m.model.training.checkpoint import check_trained_on, codes_source

    token_run = tmp_path / "hifigpt"
    token_run.mkdir()
    (token_run / "config.json").write_text(json.dumps({"kind": "hifigpt", "config": {}, "data": {
        "vq_run": str(vq_run.resolve())}}))
    assert codes_source(decoder_run) == vq_run.resolve()
    check_trained_on(token_run, vq_run)
    check_trained_on(token_run, decoder_run)
    on_decoder_run = tmp_path / "trained_with_the_decoder_run"
    on_decoder_run.mkdir()
    (on_decoder_run / "config.json").write_text(json.dumps({"kind": "hifigpt", "config": {}, "data": {
        "vq_run": str(decoder_run.resolve())}}))
    check_trained_on(on_decoder_run, vq_run)
    other = tmp_path / "other_vq"
    assert main(["train", "vq", "--data", str(data_dir), "--out", str(other), *TINY, *FEW_STEPS[:2],
                 "--threads", "1"]) == 0
    for run in (token_run, on_decoder_run):
        with pytest.raises(ValueError, match="trained on the codes of"):
            check_trained_on(run, other)
