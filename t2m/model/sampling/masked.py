"""The PyTorch reference decoder of the masked family: the modules as steps of the shared loop (t2m.decoding.masked).

The service steps the same loop over the exported graphs, so the recipe (re-masking by confidence, guidance per
stage, top-k, temperature, the order of random draws) is written once, and a fixed seed gives the same tokens through
the modules and through the graphs whenever their logits agree.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from t2m.decoding.masked import MaskedJob, MaskedStep, ResidualStep, sample_token_maps
from t2m.model.networks.masked_transformer import MaskedTransformer
from t2m.model.networks.residual_transformer import ResidualTransformer

__all__ = ["TorchMaskedStep", "TorchResidualStep", "generate_token_maps"]


class TorchMaskedStep:
    """MaskedTransformer.forward with numpy in and out."""

    def __init__(self, model: MaskedTransformer) -> None:
        self.model = model.eval()
        self.columns, self.mask_id = model.config.columns, model.config.mask_id

    @torch.no_grad()
    def __call__(self, tokens: np.ndarray, cond: np.ndarray, length: np.ndarray) -> np.ndarray:
        return self.model(torch.from_numpy(tokens), torch.from_numpy(cond), torch.from_numpy(length)).numpy()


class TorchResidualStep:
    """ResidualTransformer.forward with numpy in and out."""

    def __init__(self, model: ResidualTransformer) -> None:
        self.model = model.eval()
        self.layers, self.pad_id, self.mask_id = model.config.residual_layers, model.pad_id, model.mask_id

    @torch.no_grad()
    def __call__(self, codes: np.ndarray, layer: np.ndarray, cond: np.ndarray, length: np.ndarray) -> np.ndarray:
        return self.model(torch.from_numpy(codes), torch.from_numpy(layer), torch.from_numpy(cond),
                          torch.from_numpy(length)).numpy()


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
