"""Quantisers: shapes, EMA update, dead-code reset, straight-through gradients, residual decoding and dropout."""
from __future__ import annotations

import pytest
import torch

from t2m.model.networks.quantizers import (
    EMAResetQuantizer,
    PlainQuantizer,
    ResidualQuantizer,
    code_perplexity,
    nearest_codes,
)

torch.set_num_threads(1)


@pytest.mark.parametrize(
    "quantizer, codes_shape",
    [
        (EMAResetQuantizer(16, 8), (2, 5)),
        (PlainQuantizer(16, 8), (2, 5)),
        (ResidualQuantizer(16, 8, num_layers=3, dropout=0.0), (2, 5, 3)),
    ],
)
def test_shapes_and_outputs(quantizer, codes_shape):
    torch.manual_seed(0)
    x = torch.randn(2, 5, 8)
    quantized, codes, loss, perplexity = quantizer.train()(x)
    assert quantized.shape == x.shape
    assert codes.shape == codes_shape and codes.dtype == torch.long
    assert loss.dim() == 0 and loss.item() >= 0
    assert 1.0 <= perplexity.item() <= 16.0
    assert quantizer.codes_to_latent(codes).shape == x.shape


def test_eval_forward_returns_nearest_codebook_vectors_and_no_update():
    torch.manual_seed(0)
    quantizer = EMAResetQuantizer(8, 4).eval()
    before = quantizer.codebook.clone()
    x = torch.randn(3, 7, 4)
    quantized, codes, _, _ = quantizer(x)
    assert torch.equal(codes.reshape(-1), nearest_codes(x.reshape(-1, 4), before))
    assert torch.allclose(quantized, before[codes])
    assert torch.equal(quantizer.codebook, before)


def test_first_training_batch_initialises_the_codebook_from_the_batch():
    torch.manual_seed(0)
    quantizer = EMAResetQuantizer(8, 4, mu=0.0).train()
    x = torch.randn(1, 32, 4) * 10 + 100  # far from the random initial codebook
    quantizer(x)
    # every code is one of the batch vectors (or the mean of those assigned to it): all in the batch's range
    assert quantizer.codebook.min() > 50
    assert bool(quantizer.initialized)


def test_ema_moves_a_used_code_toward_its_assigned_vectors():
    quantizer = EMAResetQuantizer(2, 2, mu=0.5).train()
    quantizer.initialized.fill_(True)
    quantizer.codebook.copy_(torch.tensor([[0.0, 0.0], [10.0, 10.0]]))
    quantizer.code_sum.copy_(quantizer.codebook)
    quantizer.code_count.fill_(1.0)
    x = torch.tensor([[[1.0, 1.0], [1.0, 1.0], [9.0, 9.0], [9.0, 9.0]]])
    quantizer(x)
    # code 0: sum = 0.5 * 0 + 0.5 * 2 = 1 (per channel), count = 0.5 + 0.5 * 2 = 1.5 -> 2/3
    assert torch.allclose(quantizer.codebook[0], torch.tensor([2 / 3, 2 / 3]), atol=1e-6)
    # code 1: sum = 0.5 * 10 + 0.5 * 18 = 14, count 1.5 -> 9.333
    assert torch.allclose(quantizer.codebook[1], torch.tensor([14 / 1.5, 14 / 1.5]), atol=1e-5)


def test_dead_codes_are_reset_to_batch_vectors():
    torch.manual_seed(0)
    nb_code, dim = 8, 3
    quantizer = EMAResetQuantizer(nb_code, dim, mu=0.9).train()
    quantizer.initialized.fill_(True)
    far = torch.full((4, dim), 1000.0)  # codes 4..7 sit far away: no latent picks them
    near = torch.randn(4, dim)
    quantizer.codebook.copy_(torch.cat([near, far]))
    quantizer.code_sum.copy_(quantizer.codebook)
    quantizer.code_count.copy_(torch.tensor([1.0] * 4 + [0.5] * 4))  # dead ones already below the threshold
    x = torch.randn(1, 64, dim)  # more vectors than codes: the reset draws batch rows exactly (no noise)
    _, codes, _, _ = quantizer(x)
    assert set(codes.unique().tolist()) <= {0, 1, 2, 3}
    batch = x.reshape(-1, dim)
    for code in range(4, 8):
        moved_to = quantizer.codebook[code]
        assert moved_to.abs().max() < 100, f"dead code {code} was not reset"
        assert (batch - moved_to).abs().sum(dim=1).min() < 1e-6, f"code {code} is not a batch vector"
    # a second batch now uses some of the revived codes
    _, codes, _, _ = quantizer(torch.randn(1, 64, dim))
    assert len(set(codes.unique().tolist()) & {4, 5, 6, 7}) > 0


def test_straight_through_gradient_reaches_the_input():
    torch.manual_seed(0)
    for quantizer in (EMAResetQuantizer(8, 4), PlainQuantizer(8, 4), ResidualQuantizer(8, 4, 2, dropout=0.0)):
        x = torch.randn(2, 3, 4, requires_grad=True)
        quantized, _, _, _ = quantizer.train()(x)
        quantized.sum().backward()
        assert torch.allclose(x.grad, torch.ones_like(x)), type(quantizer).__name__


def test_plain_quantizer_codebook_learns_from_its_loss():
    torch.manual_seed(0)
    quantizer = PlainQuantizer(8, 4).train()
    x = torch.randn(2, 6, 4)
    _, _, loss, _ = quantizer(x)
    loss.backward()
    assert quantizer.codebook.grad is not None and quantizer.codebook.grad.abs().sum() > 0


def test_residual_decode_is_the_sum_of_layer_latents():
    torch.manual_seed(0)
    quantizer = ResidualQuantizer(16, 4, num_layers=3, dropout=0.0).train()
    for _ in range(3):
        quantizer(torch.randn(4, 8, 4))  # initialise the codebooks from data
    quantizer.eval()
    x = torch.randn(2, 5, 4)
    quantized, codes, _, _ = quantizer(x)
    manual = sum(quantizer.layers[i].codebook[codes[..., i]] for i in range(3))
    assert torch.allclose(quantizer.codes_to_latent(codes), manual, atol=1e-6)
    assert torch.allclose(quantized, manual, atol=1e-5)
    # more layers -> the residual gets smaller
    errors = [(x - quantizer.codes_to_latent(codes[..., : r + 1])).pow(2).mean().item() for r in range(3)]
    assert errors[2] < errors[0]


def test_quantizer_dropout_uses_fewer_layers_in_training_only():
    torch.manual_seed(0)
    quantizer = ResidualQuantizer(8, 4, num_layers=4, dropout=1.0).train()
    used = []
    for _ in range(40):
        _, codes, _, _ = quantizer(torch.randn(2, 3, 4))
        active = quantizer.last_active_layers
        used.append(active)
        assert (codes[..., :active] >= 0).all() and (codes[..., active:] == -1).all()
    assert min(used) == 1 and max(used) == 4 and sum(used) / len(used) < 3.5
    quantizer.eval()
    _, codes, _, _ = quantizer(torch.randn(2, 3, 4))
    assert quantizer.last_active_layers == 4 and (codes >= 0).all()
    # -1 codes decode as "layer unused": the same latent as giving only the used layers
    partial = codes.clone()
    partial[..., 2:] = -1
    torch.testing.assert_close(quantizer.codes_to_latent(partial), quantizer.codes_to_latent(codes[..., :2]))


def test_loading_a_codebook_keeps_it_on_the_next_training_step():
    source = EMAResetQuantizer(8, 4)
    source.codebook.copy_(torch.arange(32, dtype=torch.float32).view(8, 4))
    target = EMAResetQuantizer(8, 4)
    target.load_state_dict(source.state_dict(), strict=True)
    assert list(target.state_dict()) == ["codebook"]
    assert bool(target.initialized)
    target.train()(torch.arange(32, dtype=torch.float32).view(1, 8, 4))  # each vector hits its own code
    assert torch.allclose(target.codebook, source.codebook)


def test_perplexity_extremes():
    assert code_perplexity(torch.zeros(100, dtype=torch.long), 8).item() == pytest.approx(1.0)
    assert code_perplexity(torch.arange(8).repeat(10), 8).item() == pytest.approx(8.0, rel=1e-4)


def test_shared_codebook_one_dictionary_for_every_depth():
    """T2M-HiFiGPT's RVQ: one codebook (key layers.0.codebook), a greedy search at each depth over it, one EMA
    update per batch pooled over the depths."""
    torch.manual_seed(0)
    quantizer = ResidualQuantizer(32, 4, num_layers=4, dropout=0.0, shared=True).train()
    assert list(quantizer.state_dict()) == ["layers.0.codebook"]
    for _ in range(5):
        quantizer(torch.randn(8, 16, 4))
    quantizer.eval()
    x = torch.randn(3, 7, 4)
    quantized, codes, _, _ = quantizer(x)
    book = quantizer.layers[0].codebook
    residual = x.clone()
    for depth in range(4):   # each depth: the nearest code of what the earlier depths left over
        assert torch.equal(codes[..., depth], nearest_codes(residual.reshape(-1, 4), book).view(3, 7))
        residual = residual - book[codes[..., depth]]
    assert torch.allclose(quantizer.codes_to_latent(codes), sum(book[codes[..., d]] for d in range(4)), atol=1e-6)
    assert torch.allclose(quantized, quantizer.codes_to_latent(codes), atol=1e-5)
    errors = [(x - quantizer.codes_to_latent(codes[..., :r])).pow(2).mean().item() for r in (1, 4)]
    assert errors[1] < errors[0]


def test_shared_codebook_update_pools_all_depths():
    torch.manual_seed(0)
    quantizer = ResidualQuantizer(8, 2, num_layers=3, dropout=0.0, shared=True).train()
    layer = quantizer.layers[0]
    quantizer(torch.randn(4, 4, 2))  # initialises the codebook from the batch
    calls = []
    original = layer.update
    layer.update = lambda flat, codes: calls.append((flat.shape, codes.shape)) or original(flat, codes)
    quantizer(torch.randn(4, 4, 2))
    assert calls == [(torch.Size([48, 2]), torch.Size([48]))]   # one update: 3 depths x 16 latents
