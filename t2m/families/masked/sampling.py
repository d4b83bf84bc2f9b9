"""The PyTorch reference decoder of the masked family: the modules as steps of the shared loop
(t2m.families.masked.loop).

The service steps the same loop over the exported graphs, so the recipe (re-masking by confidence, guidance per
stage, top-k, temperature, the order of random draws) is written once, and a fixed seed gives the same tokens through
the modules and through the graphs whenever their logits agree.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from t2m.families.gpt.sampling import on_device
from t2m.families.masked.loop import MaskedJob, MaskedStep, ResidualStep, sample_token_maps
from t2m.families.masked.masked_transformer import MaskedTransformer
from t2m.families.masked.residual_transformer import ResidualTransformer

__all__ = ["TorchMaskedStep", "TorchResidualStep", "generate_token_maps"]


class TorchMaskedStep:
    """MaskedTransformer.forward with numpy in and out (on `device` when given: the GPU benchmark)."""

    def __init__(self, model: MaskedTransformer, device: torch.device | str | None = None) -> None:
        self.model = model.eval()
        self.device = None if device is None else torch.device(device)
        self.columns, self.mask_id = model.config.columns, model.config.mask_id

    @torch.no_grad()
    def __call__(self, tokens: np.ndarray, cond: np.ndarray, length: np.ndarray) -> np.ndarray:
        device = self.device
        return self.model(on_device(tokens, device), on_device(cond, device), on_device(length, device)).cpu().numpy()


class TorchResidualStep:
    """ResidualTransformer.forward with numpy in and out (on `device` when given)."""

    def __init__(self, model: ResidualTransformer, device: torch.device | str | None = None) -> None:
        self.model = model.eval()
        self.device = None if device is None else torch.device(device)
        self.layers, self.pad_id, self.mask_id = model.config.residual_layers, model.pad_id, model.mask_id

    @torch.no_grad()
    def __call__(self, codes: np.ndarray, layer: np.ndarray, cond: np.ndarray, length: np.ndarray) -> np.ndarray:
        device = self.device
        return self.model(on_device(codes, device), on_device(layer, device), on_device(cond, device),
                          on_device(length, device)).cpu().numpy()


def generate_token_maps(masked: MaskedTransformer | MaskedStep, residual: ResidualTransformer | ResidualStep | None,
                        cond: torch.Tensor | np.ndarray, rows: Sequence[int], *, steps: int = 10,
                        guidance: float = 4.0, residual_guidance: float = 5.0, top_k: int | None = None,
                        residual_top_k: int | None = None, temperature: float = 1.0,
                        rng: np.random.Generator | int | None = None, greedy: bool = False) -> np.ndarray:
    """Code maps [B, max(rows), C, R] (-1 = unused layer or past a motion's rows) for texts cond [B, Dt]: the shared
    loop with every motion as one segment of one request. `masked`/`residual` may be modules or ready steps."""
    masked_step: MaskedStep = TorchMaskedStep(masked) if isinstance(masked, MaskedTransformer) else masked
    residual_step: ResidualStep | None = (TorchResidualStep(residual) if isinstance(residual, ResidualTransformer)
                                          else residual)
    conds = np.asarray(cond.detach().cpu().numpy() if isinstance(cond, torch.Tensor) else cond, dtype=np.float32)
    generator = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    job = MaskedJob(conds=conds, rows=[int(r) for r in rows], rng=generator, steps=steps, guidance=guidance,
                    residual_guidance=residual_guidance, temperature=temperature, top_k=top_k,
                    residual_top_k=residual_top_k, greedy=greedy)
    (maps,) = sample_token_maps(masked_step, residual_step, [job])
    if maps is None:  # pragma: no cover - a job without a cancel callback is never cancelled
        raise RuntimeError("the reference decoder's job was cancelled")
    layers = maps[0].shape[-1]
    out = np.full((len(maps), max(rows), maps[0].shape[1], layers), -1, dtype=np.int64)
    for index, token_map in enumerate(maps):
        out[index, :len(token_map)] = token_map
    return out
