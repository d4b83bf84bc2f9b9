"""gpt_step.onnx: one autoregressive step of MotionGPT with an explicit KV cache.

Inputs (docs/contracts.md): cond [B, Dt], token [B], position [1], length [B] (only when the model was
trained with length conditioning), past_kv [n_layer, 2, B, n_head, P, head_dim] with P = position.
Outputs: logits [B, K + 1], present_kv [n_layer, 2, B, n_head, P + 1, head_dim].

Step 0 feeds the condition token with a zero-length past (P = 0); onnxruntime accepts empty tensors
on the Concat/MatMul path, so one graph serves every step (checked by tests/export/test_parity.py).
Batch and past length are dynamic; the same graph runs the cond/uncond guidance pair as a batch of 2.
"""
from __future__ import annotations

from pathlib import Path

import torch
from torch import nn

from t2m.export.graphs.export import export_graph
from t2m.families.gpt.fixed_cache import empty_fixed_cache, fixed_cache_step
from t2m.families.gpt.network import MotionGPT


class GptStepGraph(nn.Module):
    """MotionGPT.forward_step with a length input (length-conditioned models)."""

    def __init__(self, gpt: MotionGPT) -> None:
        super().__init__()
        self.gpt = gpt

    def forward(self, cond, token, position, length, past_kv):
        return self.gpt.forward_step(cond, token, position, length, past_kv)


class GptStepGraphNoLength(nn.Module):
    """MotionGPT.forward_step for models without length conditioning: the graph has no ``length`` input."""

    def __init__(self, gpt: MotionGPT) -> None:
        super().__init__()
        self.gpt = gpt

    def forward(self, cond, token, position, past_kv):
        return self.gpt.forward_step(cond, token, position, None, past_kv)


def step_input_names(gpt: MotionGPT) -> list[str]:
    names = ["cond", "token", "position"]
    if gpt.config.length_conditioning:
        names.append("length")
    return names + ["past_kv"]


def example_step_inputs(gpt: MotionGPT, batch: int = 2, past: int = 3) -> dict[str, torch.Tensor]:
    """Tracing inputs: a non-empty past so the traced graph is the general case (P = 0 works too)."""
    c = gpt.config
    generator = torch.Generator().manual_seed(0)
    inputs = {
        "cond": torch.randn(batch, c.text_dim, generator=generator),
        "token": torch.randint(0, c.codebook_size, (batch,), generator=generator),
        "position": torch.tensor([past], dtype=torch.long),
        "length": torch.tensor([0, 7][:batch] + [0] * max(0, batch - 2), dtype=torch.long),
        "past_kv": torch.randn(c.n_layer, 2, batch, c.n_head, past, c.head_dim, generator=generator),
    }
    return {name: inputs[name] for name in step_input_names(gpt)}


def export_gpt_step(gpt: MotionGPT, path: str | Path) -> Path:
    """Write gpt_step.onnx for ``gpt`` (dynamic batch and past length)."""
    gpt = gpt.eval()
    graph = GptStepGraph(gpt) if gpt.config.length_conditioning else GptStepGraphNoLength(gpt)
    inputs = example_step_inputs(gpt)
    dynamic: dict[str, dict[int, str]] = {name: {0: "batch"} for name in ("cond", "token", "length") if name in inputs}
    dynamic["past_kv"] = {2: "batch", 4: "past"}
    dynamic["logits"] = {0: "batch"}
    dynamic["present_kv"] = {2: "batch", 4: "past_plus_1"}
    return export_graph(
        graph, tuple(inputs.values()), path, input_names=list(inputs), output_names=["logits", "present_kv"],
        dynamic_axes=dynamic,
    )


class GptFixedCacheStepGraph(nn.Module):
    """fixed_cache_step (t2m/families/gpt/fixed_cache.py) with a length input, or without one."""

    def __init__(self, gpt: MotionGPT) -> None:
        super().__init__()
        self.gpt = gpt

    def forward(self, cond, token, position, *rest):
        length, past_kv = rest if self.gpt.config.length_conditioning else (None, *rest)
        return fixed_cache_step(self.gpt, cond, token, position, length, past_kv)


def export_gpt_fixed_cache_step(gpt: MotionGPT, path: str | Path, capacity: int | None = None) -> Path:
    """Write gpt_step_fixed.onnx: the step over a cache of `capacity` positions (block_size by default), each row at
    its own position [B]; only the batch is dynamic (docs/gpu.md, "CUDA graphs")."""
    gpt = gpt.eval()
    inputs = example_step_inputs(gpt)
    inputs["position"] = torch.tensor([3, 0], dtype=torch.long)        # rows at different positions
    inputs["past_kv"] = torch.randn_like(empty_fixed_cache(gpt, 2, capacity))
    dynamic: dict[str, dict[int, str]] = {name: {0: "batch"} for name in ("cond", "token", "position", "length")
                                          if name in inputs}
    dynamic["logits"] = {0: "batch"}
    dynamic["past_kv"] = dynamic["present_kv"] = {2: "batch"}
    return export_graph(
        GptFixedCacheStepGraph(gpt), tuple(inputs.values()), path, input_names=list(inputs),
        output_names=["logits", "present_kv"], dynamic_axes=dynamic,
    )
