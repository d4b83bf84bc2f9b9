"""MotionVQVAE: T2M-GPT's key layout, shapes, and that training steps lower the loss."""
from __future__ import annotations

import pytest
import torch

from t2m.model.networks.vqvae import MotionVQVAE, VQConfig
from t2m.model.training.train_vq import vq_loss

torch.set_num_threads(1)


def t2m_gpt_vq_state_dict(feat: int, width: int, code_dim: int, nb_code: int,
                          down_t: int = 2) -> dict[str, torch.Tensor]:
    """Keys and shapes as in docs/t2m-gpt-checkpoints.md (the 'vqvae.' prefix removed), at small sizes."""
    state: dict[str, torch.Tensor] = {}

    def conv(name: str, out_ch: int, in_ch: int, k: int) -> None:
        state[f"{name}.weight"] = torch.randn(out_ch, in_ch, k)
        state[f"{name}.bias"] = torch.randn(out_ch)

    def resnet(name: str) -> None:
        for block in range(3):
            conv(f"{name}.model.{block}.conv1", width, width, 3)
            conv(f"{name}.model.{block}.conv2", width, width, 1)

    conv("encoder.model.0", width, feat, 3)
    for i in range(2, 2 + down_t):
        conv(f"encoder.model.{i}.0", width, width, 4)
        resnet(f"encoder.model.{i}.1")
    conv(f"encoder.model.{2 + down_t}", code_dim, width, 3)
    conv("decoder.model.0", width, code_dim, 3)
    for i in range(2, 2 + down_t):
        resnet(f"decoder.model.{i}.0")
        conv(f"decoder.model.{i}.2", width, width, 3)
    conv(f"decoder.model.{2 + down_t}", width, width, 3)
    conv(f"decoder.model.{4 + down_t}", feat, width, 3)
    state["quantizer.codebook"] = torch.randn(nb_code, code_dim)
    return state


def test_t2m_gpt_shaped_state_dict_loads_strict():
    state = t2m_gpt_vq_state_dict(feat=263, width=24, code_dim=16, nb_code=32)
    assert len(state) == 67  # the released checkpoint's tensor count
    model = MotionVQVAE(VQConfig(width=24, code_dim=16, nb_code=32))
    model.load_state_dict(state, strict=True)
    assert torch.equal(model.quantizer.codebook, state["quantizer.codebook"])
    # the loaded weights are the ones used: decoding code 0 goes through the loaded first conv
    assert torch.equal(model.decoder.model[0].weight, state["decoder.model.0.weight"])


def test_momask_style_residual_keys_load_strict():
    state = t2m_gpt_vq_state_dict(feat=263, width=24, code_dim=16, nb_code=32)
    codebook = state.pop("quantizer.codebook")
    for layer in range(3):
        state[f"quantizer.layers.{layer}.codebook"] = codebook + layer
    model = MotionVQVAE(VQConfig(width=24, code_dim=16, nb_code=32, quantizer="residual", residual_layers=3))
    model.load_state_dict(state, strict=True)


def test_resblock_order_and_dilations_match_t2m_gpt():
    model = MotionVQVAE(VQConfig(width=8, code_dim=8, nb_code=8))
    dilations = [block.conv1.dilation[0] for block in model.encoder.model[2][1].model]
    assert dilations == [9, 3, 1]
    assert [b.conv1.padding[0] for b in model.decoder.model[2][0].model] == [9, 3, 1]


@pytest.mark.parametrize("quantizer", ["ema_reset", "plain", "residual"])
def test_shapes_encode_decode(quantizer):
    torch.manual_seed(0)
    model = MotionVQVAE(VQConfig(width=16, code_dim=8, nb_code=16, quantizer=quantizer, residual_layers=2))
    x = torch.randn(2, 32, 263)
    recon, _ = model(x)
    assert recon.shape == x.shape
    codes = model.encode(x)
    assert codes.shape == ((2, 8, 2) if quantizer == "residual" else (2, 8))
    assert model.decode(codes).shape == (2, 32, 263)
    # encode of an arbitrary length clip: floor(T / 4) codes
    assert model.encode(torch.randn(1, 37, 263)).shape[1] == 9


def test_bad_inputs_name_the_problem():
    model = MotionVQVAE(VQConfig(width=8, code_dim=8, nb_code=8))
    with pytest.raises(ValueError, match="263"):
        model(torch.randn(1, 16, 251))
    with pytest.raises(ValueError, match="multiple of 4"):
        model(torch.randn(1, 18, 263))
    with pytest.raises(ValueError, match="quantizer"):
        VQConfig(quantizer="gumbel")


def fixed_windows() -> torch.Tensor:
    """Four normalised 64-frame windows of real motion (the HumanML3D sample in tests/fixtures)."""

    from synthetic_motion_data import _source_motion

    features, mean, std = _source_motion()
    normalised = torch.from_numpy((features - mean) / std).float()
    return torch.stack([normalised[i : i + 64] for i in (0, 30, 60, 100)])


@pytest.mark.parametrize("quantizer", ["ema_reset", "residual"])
def test_a_few_training_steps_lower_the_loss_on_fixed_data(quantizer):
    torch.manual_seed(0)
    model = MotionVQVAE(VQConfig(width=32, code_dim=16, nb_code=32, quantizer=quantizer, residual_layers=2)).train()
    x = fixed_windows()
    optimizer = torch.optim.AdamW(model.parameters(), lr=1e-3)
    losses = []
    for _ in range(30):
        loss, _ = vq_loss(model, x)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    assert sum(losses[-3:]) / 3 < 0.85 * losses[0], losses


def test_eight_frames_per_code_with_a_shared_residual_codebook():
    """T2M-HiFiGPT's RVQ-VAE: down_t 3 (8 frames a code), R depths of one codebook; decode takes [B, T, R] with -1
    for unused depths."""
    torch.manual_seed(0)
    vq = MotionVQVAE(VQConfig(width=16, code_dim=8, nb_code=16, down_t=3, depth=1, quantizer="residual",
                              residual_layers=3, shared_codebook=True)).eval()
    assert vq.frames_per_token == 8
    x = torch.randn(2, 32, 263)
    codes = vq.encode(x)
    assert codes.shape == (2, 4, 3)
    assert vq.decode(codes).shape == (2, 32, 263)
    partial = codes.clone()
    partial[..., 1:] = -1
    torch.testing.assert_close(vq.decode(partial), vq.decode(codes[..., :1]))
    with pytest.raises(ValueError, match="multiple of 8"):
        vq(torch.randn(1, 36, 263))
    assert not VQConfig(quantizer="ema_reset", shared_codebook=True).shared_codebook
