"""onnxruntime vs PyTorch in float32: GPT step graph (50-step greedy rollout with the guidance pair, length
conditioning on and off), decoder (plain and residual VQ), and the real MiniLM text encoder."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from t2m.export.graphs.decoder import export_decoder
from t2m.export.kit.parity import decoder_parity, text_parity
from t2m.families.gpt.export_graphs import export_gpt_step
from t2m.families.gpt.network import GPTConfig, MotionGPT
from t2m.families.gpt.parity import gpt_parity
from t2m.model.networks.vqvae import MotionVQVAE, VQConfig

TOLERANCE = 1e-4


def spread_weights(module: torch.nn.Module, std: float, seed: int) -> None:
    """Larger random weights than the init's 0.02, so greedy rollouts visit many different codes."""
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for parameter in module.parameters():
            if parameter.dim() >= 2:
                parameter.copy_(torch.randn(parameter.shape, generator=generator) * std)


@pytest.mark.parametrize("length_conditioning", [True, False])
def test_gpt_step_graph_matches_pytorch_over_a_50_step_guided_rollout(tmp_path, length_conditioning):
    torch.manual_seed(0)
    gpt = MotionGPT(GPTConfig(codebook_size=64, embed=64, n_head=4, n_layer_base=2, n_layer_head=2, text_dim=32,
                              length_conditioning=length_conditioning)).eval()
    spread_weights(gpt, 0.15, seed=1)
    path = export_gpt_step(gpt, tmp_path / "gpt_step.onnx")
    report = gpt_parity(gpt, path, steps=50, guidance=3.0, batch=1)
    assert report.steps == 50 and report.rows == 2  # the cond row and the zero-condition row in one batch
    assert report.codes_identical
    assert report.max_abs_logit_diff <= TOLERANCE, report
    assert report.max_abs_diff_vs_recompute <= TOLERANCE, report  # KV cache == full-prefix recomputation


def test_gpt_parity_detects_a_different_model(tmp_path):
    """The comparison can fail: a graph exported from other weights is caught."""
    config = GPTConfig(codebook_size=32, embed=32, n_head=2, n_layer_base=1, n_layer_head=1, text_dim=16)
    torch.manual_seed(0)
    exported, other = MotionGPT(config).eval(), MotionGPT(config).eval()
    spread_weights(exported, 0.15, seed=1)
    spread_weights(other, 0.15, seed=2)
    path = export_gpt_step(exported, tmp_path / "gpt_step.onnx")
    report = gpt_parity(other, path, steps=20, guidance=3.0)
    assert report.max_abs_logit_diff > TOLERANCE and not report.codes_identical


@pytest.mark.parametrize("quantizer", ["ema_reset", "residual"])
def test_decoder_graph_matches_pytorch(tmp_path, quantizer):
    torch.manual_seed(0)
    vq = MotionVQVAE(VQConfig(width=48, code_dim=32, nb_code=64, depth=2, quantizer=quantizer,
                              residual_layers=3)).eval()
    rng = np.random.default_rng(0)
    mean = rng.normal(size=263).astype(np.float32)
    std = rng.uniform(0.2, 2.0, size=263).astype(np.float32)
    path = export_decoder(vq, mean, std, tmp_path / "decoder.onnx")
    for tokens in (1, 12, 50):  # one exported graph, any length
        report = decoder_parity(vq, mean, std, path, batch=2, tokens=tokens, seed=tokens)
        assert report.shape == (2, 4 * tokens, 263)
        assert report.max_abs_diff <= TOLERANCE, report


def test_minilm_text_graph_matches_the_pytorch_encoder(exported_runs, minilm_encoder):
    directory, _ = exported_runs
    texts = ["a person walks forward and then turns around", "Jump!",
             "the person " + "slowly " * 80 + "sits down"]  # longer than max_length: truncated the same way
    report = text_parity(minilm_encoder, directory / "text_encoder.onnx", directory / "tokenizer.json", texts)
    assert report.shape == (3, 384)
    assert report.max_abs_diff <= TOLERANCE, report


@pytest.mark.slow
def test_the_dynamo_exporter_gives_the_same_step_graph(tmp_path, monkeypatch):
    """The alternative exporter (graph_export.USE_DYNAMO) also passes parity, P = 0 included (minutes: slow)."""
    import t2m.export.graphs.export as graph_export

    monkeypatch.setattr(graph_export, "USE_DYNAMO", True)
    torch.manual_seed(0)
    gpt = MotionGPT(GPTConfig(codebook_size=32, embed=32, n_head=2, n_layer_base=1, n_layer_head=1, text_dim=16)).eval()
    spread_weights(gpt, 0.15, seed=1)
    report = gpt_parity(gpt, export_gpt_step(gpt, tmp_path / "gpt_step.onnx"), steps=20, guidance=3.0)
    assert report.codes_identical and report.max_abs_logit_diff <= TOLERANCE
