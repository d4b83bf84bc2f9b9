"""ONNX graphs of the masked family, and their parity with PyTorch. The decoding loops stay outside, in the host.

masked.onnx     inputs  tokens int64 [B, T, C]   codes, mask_id = K where still to predict (-1 / anything past length)
                        cond float32 [B, Dt]     text feature (zeros = the null condition)
                        length int64 [B]         real token rows
                output  logits float32 [B, T, C, K]
residual.onnx   inputs  codes int64 [B, T, C, R] the layers below ``layer`` are read (-1 = unused), the rest ignored
                        layer int64 [B]          the layer to predict, 1..R-1
                        cond float32 [B, Dt], length int64 [B]
                output  logits float32 [B, T, C, K + 1]   (K = pad: "layer unused")
decoder.onnx    input   codes int64 [B, T, C, R] (a joint VQ, or a 1D VQ with C = 1; -1 = layer unused)
                output  features float32 [B, 4T, D]  de-normalised (x * std + mean inside, as the GPT bundle's)
length.onnx     input   cond float32 [B, Dt]  ->  logits float32 [B, max_tokens + 1] over token-row counts (optional)

B and T are dynamic; C, R, K and Dt are fixed by the model. Guidance runs the condition and null rows as one
batch. The graphs are the models' own forward passes.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from t2m.export.graphs.decoder import DecoderGraph
from t2m.export.graphs.export import export_graph, ort_session
from t2m.export.kit.parity import TensorParity
from t2m.families.masked.length_estimator import LengthEstimator
from t2m.families.masked.masked_transformer import MaskedTransformer
from t2m.families.masked.residual_transformer import ResidualTransformer
from t2m.families.masked.sampling import generate_token_maps
from t2m.model.networks.fused_vqvae import FusedVQVAE
from t2m.model.networks.joint_vqvae import JointVQVAE
from t2m.model.networks.vqvae import MotionVQVAE
from t2m.runtime.onnx_step import OnnxMaskedStep, OnnxResidualStep

DYNAMIC = {0: "batch", 1: "tokens"}
MapVQ = JointVQVAE | MotionVQVAE | FusedVQVAE


class MaskedGraph(nn.Module):
    """(tokens, cond, length) -> logits, the argument order of masked.onnx."""

    def __init__(self, model: MaskedTransformer) -> None:
        super().__init__()
        self.model = model

    def forward(self, tokens: torch.Tensor, cond: torch.Tensor, length: torch.Tensor) -> torch.Tensor:
        return self.model(tokens, cond, length)


class ResidualGraph(nn.Module):
    """(codes, layer, cond, length) -> logits, the argument order of residual.onnx."""

    def __init__(self, model: ResidualTransformer) -> None:
        super().__init__()
        self.model = model

    def forward(self, codes: torch.Tensor, layer: torch.Tensor, cond: torch.Tensor, length: torch.Tensor):
        return self.model(codes, layer, cond, length)


class JointDecoderGraph(DecoderGraph):
    """A joint VQ's decode(codes) * std + mean (the 1D decoder graph's checks and buffers, the joint VQ's decode)."""

    def forward(self, codes: torch.Tensor) -> torch.Tensor:
        return self.vq.decode(codes) * self.std + self.mean


class MapDecoderGraph(DecoderGraph):
    """A 1D VQ's decoder over one-column maps [B, T, 1, R] (MoMask's variant): the column dropped, then the 1D graph
    (a single-layer VQ also drops the layer axis)."""

    def forward(self, codes: torch.Tensor) -> torch.Tensor:
        codes = codes[:, :, 0]
        if self._motion_vq().config.quantizer != "residual":
            codes = codes[..., 0]
        return super().forward(codes)


class FusedDecoderGraph(DecoderGraph):
    """MoGenTS's fused VQ: decode(codes [B, T, C + 1, R]) * std + mean (the 2D map and the 1D tokens as one map)."""

    def forward(self, codes: torch.Tensor) -> torch.Tensor:
        assert isinstance(self.vq, FusedVQVAE)
        return self.vq.decode(codes) * self.std + self.mean


class LengthGraph(nn.Module):
    """cond -> logits over token-row counts 0..max_tokens, the argument order of length.onnx."""

    def __init__(self, model: LengthEstimator) -> None:
        super().__init__()
        self.model = model

    def forward(self, cond: torch.Tensor) -> torch.Tensor:
        return self.model(cond)


def map_decoder_graph(vq: MapVQ, mean: np.ndarray, std: np.ndarray) -> DecoderGraph:
    """The decoder.onnx module of any VQ: codes [B, T, C, R] -> features [B, 4T, D]."""
    if isinstance(vq, FusedVQVAE):
        return FusedDecoderGraph(vq, mean, std).eval()
    graph = JointDecoderGraph(vq, mean, std) if isinstance(vq, JointVQVAE) else MapDecoderGraph(vq, mean, std)
    return graph.eval()


def map_shape(vq: MapVQ) -> tuple[int, int]:
    """(columns, layers) of the code maps a VQ decodes (a 1D VQ: one column; a single-layer one: one layer; the
    fused VQ: its 2D columns and one for the 1D tokens)."""
    if isinstance(vq, FusedVQVAE):
        return vq.config.columns + 1, vq.config.residual_layers
    if isinstance(vq, JointVQVAE):
        return vq.config.columns, vq.config.residual_layers
    return 1, vq.config.residual_layers if vq.config.quantizer == "residual" else 1


def example_inputs(model: MaskedTransformer | ResidualTransformer, batch: int = 2, rows: int = 5,
                   seed: int = 0) -> dict[str, torch.Tensor]:
    """Inputs of either transformer graph: random codes (some masked), text features, lengths (the last padded)."""
    c = model.config
    generator = torch.Generator().manual_seed(seed)
    length = torch.full((batch,), rows, dtype=torch.long)
    length[-1] = max(1, rows - 2)
    cond = torch.randn(batch, c.text_dim, generator=generator)
    cond[-1] = 0.0 if batch > 1 else cond[-1]  # a null-condition row, as guidance sends
    if isinstance(model, MaskedTransformer):
        tokens = torch.randint(0, c.codebook_size, (batch, rows, c.columns), generator=generator)
        masked = torch.rand(tokens.shape, generator=generator) < 0.5
        tokens = torch.where(masked, torch.full_like(tokens, c.mask_id), tokens)
        return {"tokens": tokens, "cond": cond, "length": length}
    codes = torch.randint(-1, c.codebook_size, (batch, rows, c.columns, c.residual_layers), generator=generator)
    layer = torch.randint(1, c.residual_layers, (batch,), generator=generator)
    return {"codes": codes, "layer": layer, "cond": cond, "length": length}


def export_masked(model: MaskedTransformer, path: str | Path) -> Path:
    """Write masked.onnx (see the module docstring)."""
    inputs = example_inputs(model.eval())
    return export_graph(
        MaskedGraph(model).eval(), tuple(inputs.values()), path, input_names=list(inputs), output_names=["logits"],
        dynamic_axes={"tokens": DYNAMIC, "cond": {0: "batch"}, "length": {0: "batch"}, "logits": DYNAMIC},
    )


def export_residual(model: ResidualTransformer, path: str | Path) -> Path:
    """Write residual.onnx (see the module docstring)."""
    inputs = example_inputs(model.eval())
    return export_graph(
        ResidualGraph(model).eval(), tuple(inputs.values()), path, input_names=list(inputs), output_names=["logits"],
        dynamic_axes={"codes": DYNAMIC, "layer": {0: "batch"}, "cond": {0: "batch"}, "length": {0: "batch"},
                      "logits": DYNAMIC},
    )


def export_joint_decoder(vq: MapVQ, mean: np.ndarray, std: np.ndarray, path: str | Path) -> Path:
    """Write decoder.onnx for a joint VQ or a 1D one (input ``codes`` [B, T, C, R], output ``features`` [B, 4T, D])."""
    columns, layers = map_shape(vq.eval())
    generator = torch.Generator().manual_seed(0)
    codes = torch.randint(0, vq.config.nb_code, (2, 5, columns, layers), generator=generator)
    return export_graph(
        map_decoder_graph(vq, mean, std), (codes,), path, input_names=["codes"], output_names=["features"],
        dynamic_axes={"codes": DYNAMIC, "features": {0: "batch", 1: "frames"}},
    )


def export_length(model: LengthEstimator, path: str | Path) -> Path:
    """Write length.onnx (input ``cond`` [B, Dt], output ``logits`` [B, max_tokens + 1])."""
    cond = torch.randn(2, model.eval().config.text_dim, generator=torch.Generator().manual_seed(0))
    return export_graph(LengthGraph(model).eval(), (cond,), path, input_names=["cond"], output_names=["logits"],
                        dynamic_axes={"cond": {0: "batch"}, "logits": {0: "batch"}})


# --- parity -----------------------------------------------------------------------------------------------------


def _real_rows(logits: np.ndarray, length: torch.Tensor) -> np.ndarray:
    """Only the rows before each motion's length count (past it the graph's output is never read)."""
    return np.concatenate([logits[b, : int(n)].reshape(-1) for b, n in enumerate(length)])


def transformer_parity(model: MaskedTransformer | ResidualTransformer, onnx_path: str | Path, batch: int = 2,
                       rows: int = 7, seed: int = 0) -> TensorParity:
    """The exported graph vs the model on random inputs of any batch and length (logits of the real rows)."""
    inputs = example_inputs(model.eval(), batch, rows, seed)
    with torch.no_grad():
        expected = model(**inputs).numpy()
    (actual,) = ort_session(onnx_path).run(None, {k: v.numpy() for k, v in inputs.items()})
    if actual.shape != expected.shape:
        raise ValueError(f"{Path(onnx_path).name} returned {list(actual.shape)}, PyTorch {list(expected.shape)}")
    length = inputs["length"]
    difference = np.abs(_real_rows(actual, length) - _real_rows(expected, length))
    return TensorParity(tuple(actual.shape), float(difference.max()))


def joint_decoder_parity(vq: MapVQ, mean: np.ndarray, std: np.ndarray, onnx_path: str | Path,
                         batch: int = 2, rows: int = 6, seed: int = 0) -> TensorParity:
    """decoder.onnx vs vq.decode(codes) * std + mean, on random codes with some unused (-1) upper layers."""
    columns, layers = map_shape(vq.eval())
    generator = torch.Generator().manual_seed(seed)
    codes = torch.randint(0, vq.config.nb_code, (batch, rows, columns, layers), generator=generator)
    codes[0, :, :, 1:] = -1  # the first motion with its first layer only
    with torch.no_grad():
        expected = (map_decoder_graph(vq, mean, std)(codes)).numpy()
    (actual,) = ort_session(onnx_path).run(None, {"codes": codes.numpy()})
    if actual.shape != expected.shape:
        raise ValueError(f"decoder.onnx returned {list(actual.shape)}, PyTorch {list(expected.shape)}")
    return TensorParity(tuple(actual.shape), float(np.abs(actual - expected).max()))


def length_parity(model: LengthEstimator, onnx_path: str | Path, batch: int = 3, seed: int = 0) -> TensorParity:
    """length.onnx vs the estimator on random text features (and a null row)."""
    cond = torch.randn(batch, model.eval().config.text_dim, generator=torch.Generator().manual_seed(seed))
    cond[-1] = 0.0
    with torch.no_grad():
        expected = model(cond).numpy()
    (actual,) = ort_session(onnx_path).run(None, {"cond": cond.numpy()})
    if actual.shape != expected.shape:
        raise ValueError(f"length.onnx returned {list(actual.shape)}, PyTorch {list(expected.shape)}")
    return TensorParity(tuple(actual.shape), float(np.abs(actual - expected).max()))


@dataclass
class DecodeParity:
    """A full decode (mask stage, then the residual layers) run with PyTorch and with the graphs."""

    shape: tuple[int, ...]
    tokens_identical: bool
    differing_tokens: int


def decode_parity(masked: MaskedTransformer, residual: ResidualTransformer | None, masked_path: str | Path,
                  residual_path: str | Path | None, length: list[int], steps: int = 10, guidance: float = 4.0,
                  residual_guidance: float = 5.0, seed: int = 0, cond: torch.Tensor | None = None) -> DecodeParity:
    """The shared decoding loop (t2m.families.masked.loop) over the modules and over the graphs: greedy (top-k 1), so
    any
    token that differs is a difference in the graphs' logits, not in random draws. No residual model (a single-layer
    VQ): the mask stage only. ``cond`` replaces the random text features (e.g. unit_conditions for MiniLM)."""
    residual_graph = None
    if residual is not None:
        if residual_path is None:
            raise ValueError("decode_parity: a residual model needs its residual.onnx")
        residual_graph = OnnxResidualStep(ort_session(residual_path), residual.config.residual_layers, residual.pad_id,
                                          residual.mask_id)
    graphs = (OnnxMaskedStep(ort_session(masked_path), masked.config.columns, masked.config.mask_id), residual_graph)
    if cond is None:
        cond = torch.randn(len(length), masked.config.text_dim, generator=torch.Generator().manual_seed(seed))
    results = [generate_token_maps(m, r, cond, length, steps=steps, guidance=guidance,
                                   residual_guidance=residual_guidance, greedy=True)
               for m, r in ((masked, residual), graphs)]
    expected, actual = results
    differing = int((expected != actual).sum())
    return DecodeParity(tuple(actual.shape), differing == 0, differing)


# --- int8 -------------------------------------------------------------------------------------------------------


@dataclass
class TokenGraphInt8Report:
    """What int8 weights cost one token graph (masked.onnx or residual.onnx) against its float32 export."""

    max_abs_logit_diff: float       # on random inputs, real rows only
    max_abs_logit: float            # the float32 logits' scale, to read the difference against
    fp32_ms: float                  # one forward at batch 2 (a guidance pair) x `rows` rows
    int8_ms: float
    rows: int
    fp32_bytes: int
    int8_bytes: int


def token_graph_int8_report(model: MaskedTransformer | ResidualTransformer, fp32_path: str | Path,
                            int8_path: str | Path, repeats: int = 5, seed: int = 0) -> TokenGraphInt8Report:
    """Logit difference and speed of an int8 token graph vs its float32 export, at the model's longest map."""
    import time

    rows = model.config.max_tokens
    inputs = {k: v.numpy() for k, v in example_inputs(model.eval(), 2, rows, seed).items()}
    outputs, times = [], []
    for path in (fp32_path, int8_path):
        session = ort_session(path)
        session.run(None, inputs)
        start = time.perf_counter()
        for _ in range(repeats):
            (logits,) = session.run(None, inputs)
        times.append((time.perf_counter() - start) / repeats)
        outputs.append(_real_rows(logits, torch.from_numpy(inputs["length"])))
    fp32, int8 = outputs
    return TokenGraphInt8Report(
        max_abs_logit_diff=float(np.abs(fp32 - int8).max()), max_abs_logit=float(np.abs(fp32).max()),
        fp32_ms=1000 * times[0], int8_ms=1000 * times[1], rows=rows,
        fp32_bytes=Path(fp32_path).stat().st_size, int8_bytes=Path(int8_path).stat().st_size)


def unit_conditions(count: int, dim: int, seed: int = 0) -> torch.Tensor:
    """Random L2-normalised text features: where a normalised encoder's (MiniLM's) features live."""
    cond = torch.randn(count, dim, generator=torch.Generator().manual_seed(seed))
    return cond / cond.norm(dim=1, keepdim=True)
