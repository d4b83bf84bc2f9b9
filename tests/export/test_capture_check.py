"""capture_check's model of where onnxruntime's CUDA provider would copy between host and device (the copies that
make `enable_cuda_graph` refuse a session). On an H100 (docs/measurements/gpu_suite_h100_second_device_session.log) the
fixed-cache GPT step was captured and MoMask's masked/residual graphs were refused; the checker must say the same
of those graphs' shapes, and pass the masked family's graphs as exported now."""
from __future__ import annotations

from pathlib import Path

import pytest
import torch
import torch.nn.functional as F

from t2m.export.graphs.capture_check import capture_blockers
from t2m.export.graphs.export import export_graph
from t2m.families.gpt.export_graphs import export_gpt_fixed_cache_step
from t2m.families.gpt.network import GPTConfig, MotionGPT
from t2m.families.masked.export_graphs import export_masked, export_residual
from t2m.families.masked.masked_transformer import MaskedTransformer
from t2m.families.masked.residual_transformer import ResidualTransformer
from t2m.model.networks.token_transformer import TokenTransformerConfig, index_range


class _ArangeMask(torch.nn.Module):
    """The shape of what MoMask's graphs did before index_range: arange over a traced length against an input."""

    def forward(self, x: torch.Tensor, length: torch.Tensor) -> torch.Tensor:
        valid = torch.arange(x.shape[1])[None, :] < length[:, None]
        return x * valid[..., None].to(x.dtype)


class _CountedMask(_ArangeMask):
    def forward(self, x: torch.Tensor, length: torch.Tensor) -> torch.Tensor:
        valid = index_range(x.shape[1], x)[None, :] < length[:, None]
        return x * valid[..., None].to(x.dtype)


class _Attention(torch.nn.Module):
    """scaled_dot_product_attention with its scale left to the exporter (computed from Shape) or given."""

    def __init__(self, scale: float | None) -> None:
        super().__init__()
        self.scale = scale

    def forward(self, q: torch.Tensor) -> torch.Tensor:
        return F.scaled_dot_product_attention(q, q, q, scale=self.scale)


def _export(module: torch.nn.Module, args: tuple[torch.Tensor, ...], names: list[str], path: Path) -> Path:
    axes = {name: {0: "batch", 1: "rows"} if arg.dim() > 1 else {0: "batch"} for name, arg in zip(names, args)}
    return export_graph(module, args, path, input_names=names, output_names=["y"],
                        dynamic_axes={**axes, "y": {0: "batch", 1: "rows"}})


def test_an_arange_over_a_traced_length_is_a_copy_and_a_cumulative_sum_is_not(tmp_path):
    args = (torch.randn(2, 5, 3), torch.tensor([5, 3]))
    blockers = capture_blockers(_export(_ArangeMask(), args, ["x", "length"], tmp_path / "arange.onnx"))
    assert len(blockers) == 1 and blockers[0].startswith("Less"), blockers
    assert capture_blockers(_export(_CountedMask(), args, ["x", "length"], tmp_path / "counted.onnx")) == []


def test_an_attention_scale_left_to_the_exporter_is_a_copy(tmp_path):
    q = (torch.randn(2, 4, 5, 8),)
    blockers = capture_blockers(_export(_Attention(None), q, ["q"], tmp_path / "implicit.onnx"))
    assert any("from Sqrt" in line for line in blockers), blockers
    assert capture_blockers(_export(_Attention(8 ** -0.5), q, ["q"], tmp_path / "explicit.onnx")) == []


def test_the_fixed_cache_gpt_step_is_capturable(tmp_path):
    torch.manual_seed(0)
    gpt = MotionGPT(GPTConfig(codebook_size=16, embed=16, n_head=2, n_layer_base=1, n_layer_head=1, block_size=12,
                               dropout=0.0, text_dim=8))
    assert capture_blockers(export_gpt_fixed_cache_step(gpt.eval(), tmp_path / "gpt_step_fixed.onnx")) == []


@pytest.mark.parametrize("layout", ["1d", "2d"], ids=["momask", "mogents"])
def test_the_masked_familys_graphs_are_capturable(layout, tmp_path):
    two_d = layout == "2d"
    config = TokenTransformerConfig(codebook_size=16, columns=3 if two_d else 1, residual_layers=3, max_tokens=8,
                                    latent=24, n_head=2, n_layer=1, ff_size=32, dropout=0.0, text_dim=8, code_dim=8,
                                    positional=layout, spatial_attention=two_d, temporal_attention=two_d)
    torch.manual_seed(0)
    masked = export_masked(MaskedTransformer(config).eval(), tmp_path / "masked.onnx")
    residual = export_residual(ResidualTransformer(config).eval(), tmp_path / "residual.onnx")
    assert capture_blockers(masked) == [] and capture_blockers(residual) == []
