"""T2M-HiFiGPT's step graphs, and their parity with PyTorch over a seeded guided rollout. The loop stays in the host.

temporal_step.onnx  inputs  cond float32 [B, Dt]       text feature (zeros = the null condition)
                            codes int64 [B, R]         the codes of step `position` (ignored at position 0)
                            position int64 [1]         0 = the condition token
                            length int64 [B]           requested steps, 0 = free (only with length conditioning)
                            past_kv float32 [Lt, 2, B, H, P, hd]   P = position
                    outputs context float32 [B, E]     h_position: the context of step position + 1
                            stop_logit float32 [B]     "the motion ends after `position` steps"
                            present_kv [Lt, 2, B, H, P + 1, hd]
residual_step.onnx  inputs  context float32 [B, E]     read at depth 0
                            code int64 [B]             the code of depth - 1 (ignored at depth 0)
                            depth int64 [1]
                            past_kv float32 [Lr, 2, B, H, depth, hd]   (fresh at every time step)
                    outputs logits float32 [B, K]      code `depth`
                            present_kv [Lr, 2, B, H, depth + 1, hd]
decoder.onnx        codes int64 [B, T, R] (-1 = depth unused)  ->  features float32 [B, fpt T, D] (de-normalised)

One call per depth (not the whole depth loop in one graph): the per-call overhead measured at the paper's size is a
few per cent of a step, and the host keeps the one sampling recipe (t2m.families.hifigpt.loop, shared with PyTorch);
t2m/families/hifigpt/bench.py has the figures. B and the cache lengths are dynamic.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np
import torch
from torch import nn

from t2m.decoding.lockstep import SamplingJob
from t2m.export.graphs.export import export_graph, ort_session
from t2m.families.hifigpt.loop import ResidualGptStep, TemporalStep, sample_code_rows
from t2m.families.hifigpt.network import HiFiGPT
from t2m.families.hifigpt.sampling import TorchResidualGptStep, TorchTemporalStep
from t2m.runtime.onnx_step import OnnxResidualGptStep, OnnxTemporalStep

KV_DYNAMIC = {2: "batch", 4: "past"}
PRESENT_DYNAMIC = {2: "batch", 4: "past_plus_1"}


class TemporalStepGraph(nn.Module):
    """HiFiGPT.temporal_step with a length input (length-conditioned models)."""

    def __init__(self, model: HiFiGPT) -> None:
        super().__init__()
        self.model = model

    def forward(self, cond, codes, position, length, past_kv):
        return self.model.temporal_step(cond, codes, position, length, past_kv)


class TemporalStepGraphNoLength(TemporalStepGraph):
    """HiFiGPT.temporal_step for models without length conditioning: the graph has no ``length`` input."""

    def forward(self, cond, codes, position, past_kv):  # type: ignore[override]
        return self.model.temporal_step(cond, codes, position, None, past_kv)


class ResidualStepGraph(nn.Module):
    """HiFiGPT.residual_step, the argument order of residual_step.onnx."""

    def __init__(self, model: HiFiGPT) -> None:
        super().__init__()
        self.model = model

    def forward(self, context, code, depth, past_kv):
        return self.model.residual_step(context, code, depth, past_kv)


def _cache(model: HiFiGPT, tier: str, batch: int, past: int, generator: torch.Generator) -> torch.Tensor:
    empty = model.empty_cache(tier, batch)
    return torch.randn(*empty.shape[:4], past, empty.shape[5], generator=generator)


def export_temporal_step(model: HiFiGPT, path: str | Path) -> Path:
    """Write temporal_step.onnx (traced at a non-empty past: the general case; P = 0 works too)."""
    c = model.eval().config
    generator = torch.Generator().manual_seed(0)
    inputs: dict[str, torch.Tensor] = {
        "cond": torch.randn(2, c.text_dim, generator=generator),
        "codes": torch.randint(0, c.codebook_size, (2, c.depth), generator=generator),
        "position": torch.tensor([3], dtype=torch.long),
        "length": torch.tensor([0, 7], dtype=torch.long),
        "past_kv": _cache(model, "temporal", 2, 3, generator),
    }
    graph = TemporalStepGraph(model) if c.length_conditioning else TemporalStepGraphNoLength(model)
    if not c.length_conditioning:
        del inputs["length"]
    dynamic: dict[str, dict[int, str]] = {name: {0: "batch"} for name in (*inputs, "context", "stop_logit")
                                          if name not in ("position", "past_kv")}
    dynamic.update(past_kv=KV_DYNAMIC, present_kv=PRESENT_DYNAMIC)
    return export_graph(graph.eval(), tuple(inputs.values()), path, input_names=list(inputs),
                        output_names=["context", "stop_logit", "present_kv"], dynamic_axes=dynamic)


def export_residual_step(model: HiFiGPT, path: str | Path) -> Path:
    """Write residual_step.onnx (traced at depth 1 of a model with R >= 2, else at depth 0)."""
    c = model.eval().config
    generator = torch.Generator().manual_seed(0)
    depth = min(1, c.depth - 1)
    inputs = {"context": torch.randn(2, c.embed, generator=generator),
              "code": torch.randint(0, c.codebook_size, (2,), generator=generator),
              "depth": torch.tensor([depth], dtype=torch.long),
              "past_kv": _cache(model, "residual", 2, depth, generator)}
    return export_graph(ResidualStepGraph(model).eval(), tuple(inputs.values()), path, input_names=list(inputs),
                        output_names=["logits", "present_kv"],
                        dynamic_axes={"context": {0: "batch"}, "code": {0: "batch"}, "past_kv": KV_DYNAMIC,
                                      "logits": {0: "batch"}, "present_kv": PRESENT_DYNAMIC})


def onnx_steps(model: HiFiGPT, temporal_path: str | Path, residual_path: str | Path,
               threads: int = 1) -> tuple[OnnxTemporalStep, OnnxResidualGptStep]:
    """The service's steps over the two graphs (sizes from the model)."""
    c = model.config
    return (OnnxTemporalStep(ort_session(temporal_path, threads), c.depth, c.n_layer_temporal, c.n_head, c.head_dim,
                             c.length_conditioning),
            OnnxResidualGptStep(ort_session(residual_path, threads), c.n_layer_residual, c.n_head, c.head_dim))


# --- parity -----------------------------------------------------------------------------------------------------


class _Compared:
    """Runs a graph step and the PyTorch step on the same inputs, returns the graph's outputs and keeps the largest
    difference of each output (so a rollout fed by the graphs measures the modules along the same path)."""

    def __init__(self, graph: Any, reference: Any, names: tuple[str, ...]) -> None:
        self.graph, self.reference, self.names = graph, reference, names
        self.depth = getattr(graph, "depth", 0)
        self.worst = dict.fromkeys(names, 0.0)

    def empty_cache(self, batch: int) -> np.ndarray:
        return self.graph.empty_cache(batch)

    def __call__(self, *args: Any) -> Any:
        outputs = self.graph(*args)
        for name, got, want in zip(self.names, outputs, self.reference(*args)):
            if got.size:
                self.worst[name] = max(self.worst[name], float(np.abs(got - want).max()))
        return outputs


@dataclass
class RolloutParity:
    """A seeded guided rollout (temperature 1, random draws) with the graphs and with the modules."""

    guidance: float
    segments: int
    steps: list[int]                  # time steps each segment got (its stop) with the graphs
    max_abs_context_diff: float
    max_abs_stop_diff: float
    max_abs_logit_diff: float
    codes_identical: bool             # every code and every stop the same
    differing_codes: int


def rollout_parity(model: HiFiGPT, temporal_path: str | Path, residual_path: str | Path, guidance: float = 3.0,
                   seed: int = 0) -> RolloutParity:
    """The shared loop (t2m.families.hifigpt.loop) over the graphs and over the modules, with the same seeded
    generator: two segments of fixed length and two free ones (the stop head decides), guidance on codes and stop."""
    c = model.eval().config
    cond = np.random.default_rng(seed).normal(size=(4, c.text_dim)).astype(np.float32)
    targets: list[int | None] = [min(c.max_tokens, 6), None, min(c.max_tokens, 3), None]

    def run(temporal: Any, residual: Any) -> list[np.ndarray]:
        job = SamplingJob(conds=cond, targets=targets, guidance=guidance, temperature=1.0, top_k=None,
                          rng=np.random.default_rng(seed))
        steps = cast(TemporalStep, temporal), cast(ResidualGptStep, residual)
        (maps,) = sample_code_rows(*steps, [job], c.max_tokens)
        assert maps is not None
        return maps

    graph_temporal, graph_residual = onnx_steps(model, temporal_path, residual_path)
    temporal = _Compared(graph_temporal, TorchTemporalStep(model), ("context", "stop", "kv"))
    residual = _Compared(graph_residual, TorchResidualGptStep(model), ("logits", "kv"))
    exported = run(temporal, residual)
    reference = run(TorchTemporalStep(model), TorchResidualGptStep(model))
    same_lengths = [len(a) for a in exported] == [len(b) for b in reference]
    differing = sum(int((a != b).sum()) for a, b in zip(exported, reference) if a.shape == b.shape)
    return RolloutParity(guidance=guidance, segments=len(targets), steps=[len(m) for m in exported],
                         max_abs_context_diff=temporal.worst["context"], max_abs_stop_diff=temporal.worst["stop"],
                         max_abs_logit_diff=residual.worst["logits"],
                         codes_identical=same_lengths and differing == 0, differing_codes=differing)
