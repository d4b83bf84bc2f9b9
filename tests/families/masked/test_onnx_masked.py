"""onnxruntime vs PyTorch for the masked family's graphs: masked and residual transformers (2D joint maps and
MoMask's 1D layout) and the joint VQ decoder, at lengths other than the traced one, and a full guided decode that
must give the same tokens through the graphs as through the models."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from t2m.families.masked.export_graphs import (
    decode_parity,
    export_joint_decoder,
    export_masked,
    export_residual,
    joint_decoder_parity,
    transformer_parity,
)
from t2m.families.masked.masked_transformer import MaskedTransformer
from t2m.families.masked.residual_transformer import ResidualTransformer
from t2m.model.networks.joint_vqvae import JointVQConfig, JointVQVAE
from t2m.model.networks.token_transformer import TokenTransformerConfig

TOLERANCE = 1e-4


def spread_weights(module: torch.nn.Module, std: float, seed: int) -> None:
    """Larger random weights than the init's, so that logits differ and greedy decoding visits many codes."""
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for parameter in module.parameters():
            if parameter.dim() >= 2:
                parameter.copy_(torch.randn(parameter.shape, generator=generator) * std)


def tiny_models(columns: int, seed: int = 0) -> tuple[MaskedTransformer, ResidualTransformer]:
    config = TokenTransformerConfig(
        codebook_size=32, columns=columns, residual_layers=3, max_tokens=16, latent=32, n_head=2, n_layer=1,
        ff_size=64, dropout=0.0, text_dim=8, code_dim=16, positional="2d" if columns > 1 else "1d",
        spatial_attention=columns > 1, temporal_attention=columns > 1,
    )
    torch.manual_seed(seed)
    masked, residual = MaskedTransformer(config).eval(), ResidualTransformer(config).eval()
    spread_weights(masked, 0.15, seed + 1)
    spread_weights(residual, 0.15, seed + 2)
    return masked, residual


@pytest.fixture(scope="module", params=[6, 1], ids=["joint-map", "1d"])
def exported(request, tmp_path_factory):
    masked, residual = tiny_models(request.param)
    directory = tmp_path_factory.mktemp(f"masked{request.param}")
    return masked, residual, export_masked(masked, directory / "masked.onnx"), \
        export_residual(residual, directory / "residual.onnx")


@pytest.mark.parametrize("batch, rows", [(1, 1), (2, 7), (3, 16)])
def test_transformer_graphs_match_pytorch_at_any_batch_and_length(exported, batch, rows):
    masked, residual, masked_path, residual_path = exported
    for model, path, classes in ((masked, masked_path, 32), (residual, residual_path, 33)):
        report = transformer_parity(model, path, batch=batch, rows=rows, seed=rows)
        assert report.shape == (batch, rows, model.config.columns, classes)
        assert report.max_abs_diff <= TOLERANCE, report


def test_a_guided_greedy_decode_gives_the_same_tokens_through_the_graphs(exported):
    masked, residual, masked_path, residual_path = exported
    report = decode_parity(masked, residual, masked_path, residual_path, length=[16, 9, 3], steps=10, guidance=4.0,
                           residual_guidance=5.0)
    assert report.shape == (3, 16, masked.config.columns, 3)
    assert report.tokens_identical, report


def test_parity_detects_a_different_model(exported, tmp_path):
    masked, _, _, _ = exported
    other, _ = tiny_models(masked.config.columns, seed=5)
    report = transformer_parity(other, export_masked(masked, tmp_path / "masked.onnx"))
    assert report.max_abs_diff > TOLERANCE


@pytest.mark.parametrize("down_j", [2, 0])
def test_joint_decoder_graph_matches_pytorch(tmp_path, down_j):
    torch.manual_seed(0)
    vq = JointVQVAE(JointVQConfig(width=16, code_dim=8, nb_code=32, depth=2, down_j=down_j, residual_layers=3)).eval()
    spread_weights(vq, 0.1, seed=3)
    rng = np.random.default_rng(0)
    mean = rng.normal(size=263).astype(np.float32)
    std = rng.uniform(0.2, 2.0, size=263).astype(np.float32)
    path = export_joint_decoder(vq, mean, std, tmp_path / "decoder.onnx")
    for rows in (1, 6, 50):  # one graph, any length; the first motion uses its first layer only
        report = joint_decoder_parity(vq, mean, std, path, batch=2, rows=rows, seed=rows)
        assert report.shape == (2, 4 * rows, 263)
        assert report.max_abs_diff <= TOLERANCE, report
