"""The diffusion family's graphs (t2m/families/diffusion/family.py gives their signatures;
t2m/families/diffusion/README.md):

- denoiser.onnx: one diffusion step of a batch, MDM.forward: x_t [B, T, F], t [B] (integer steps), text [B, Dt]
  (pooled) or [B, L, Dt] + text_mask bool [B, L] (token states), length [B] (only for models that mask padded
  frames), prefix [B, P, F] (only DiP) -> x0 [B, T, F]; batch, frames and text tokens are dynamic axes;
- decoder.onnx: motion [B, T, F] (normalised frames) -> features [B, T, F] = motion * std + mean;
- text_encoder.onnx of a token-state encoder: input_ids, attention_mask [B, L] -> token_states [B, L, Dt] (the
  states of every token; padded positions are masked by the denoiser's text_mask), written by
  t2m.export.graphs.text.export_token_states_graph.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import nn

from t2m.export.graphs.export import export_graph
from t2m.families.diffusion.network import MDM

__all__ = ["DenoiserGraph", "Denormalise", "denoiser_inputs", "export_denoiser", "export_denormaliser"]


def denoiser_inputs(model: MDM) -> list[str]:
    """The denoiser graph's input names for this model's configuration, in order."""
    c = model.config
    names = ["x_t", "t", "text"]
    if c.text_tokens:
        names.append("text_mask")
    if c.mask_frames:
        names.append("length")
    if c.pred_len > 0:
        names.append("prefix")
    return names


class DenoiserGraph(nn.Module):
    """MDM.forward with the graph's inputs (only those the configuration uses) as positional arguments."""

    def __init__(self, model: MDM) -> None:
        super().__init__()
        self.model = model
        self.names = denoiser_inputs(model)

    def forward(self, *inputs: torch.Tensor) -> torch.Tensor:
        given = dict(zip(self.names, inputs))
        return self.model(given["x_t"], given["t"], given["text"], given.get("text_mask"), given.get("length"),
                          given.get("prefix"))


def export_denoiser(model: MDM, path: str | Path) -> Path:
    """Write denoiser.onnx from an MDM module (batch, frames and text tokens dynamic)."""
    c = model.config
    frames, batch, tokens = max(c.pred_len, 6), 2, 3
    examples = {"x_t": torch.randn(batch, frames, c.features), "t": torch.tensor([c.diffusion_steps - 1, 0]),
                "text": torch.randn(batch, tokens, c.text_dim) if c.text_tokens else torch.randn(batch, c.text_dim),
                "text_mask": torch.tensor([[True, True, False], [True, True, True]]),
                "length": torch.tensor([frames - 1, frames]),
                "prefix": torch.randn(batch, max(c.context_len, 1), c.features)}
    axes = {"x_t": {0: "batch", 1: "frames"}, "t": {0: "batch"},
            "text": {0: "batch", 1: "tokens"} if c.text_tokens else {0: "batch"},
            "text_mask": {0: "batch", 1: "tokens"}, "length": {0: "batch"}, "prefix": {0: "batch"},
            "x0": {0: "batch", 1: "frames"}}
    graph = DenoiserGraph(model.eval())
    return export_graph(graph, tuple(examples[name] for name in graph.names), path, graph.names, ["x0"],
                        {name: axes[name] for name in [*graph.names, "x0"]})


class Denormalise(nn.Module):
    """Normalised frames -> features: motion * std + mean (the statistics the model was trained with)."""

    mean: torch.Tensor
    std: torch.Tensor

    def __init__(self, mean: np.ndarray, std: np.ndarray) -> None:
        super().__init__()
        self.register_buffer("mean", torch.as_tensor(np.asarray(mean, np.float32)))
        self.register_buffer("std", torch.as_tensor(np.asarray(std, np.float32)))

    def forward(self, motion: torch.Tensor) -> torch.Tensor:
        return motion * self.std + self.mean


def export_denormaliser(mean: np.ndarray, std: np.ndarray, path: str | Path) -> Path:
    """Write the diffusion family's decoder.onnx."""
    return export_graph(Denormalise(mean, std), (torch.zeros(1, 4, len(mean)),), path, ["motion"], ["features"],
                        {"motion": {0: "batch", 1: "frames"}, "features": {0: "batch", 1: "frames"}})

