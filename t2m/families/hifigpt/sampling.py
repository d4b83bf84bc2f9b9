"""The PyTorch reference sampler of T2M-HiFiGPT: HiFiGPT's step methods as the steps of the shared loop
(t2m.families.hifigpt.loop).

The service runs the same loop over temporal_step.onnx and residual_step.onnx, so the recipe (guidance on code and
stop logits, temperature, top-k, the stop rule, the order of random draws) is written once; for the same seed the
reference and the service choose the same codes and the same stops whenever their logits agree.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from t2m.families.gpt.sampling import DeviceCache, evaluating, on_device, only_job, reference_job
from t2m.families.hifigpt.loop import sample_code_rows
from t2m.families.hifigpt.network import HiFiGPT

__all__ = ["TorchResidualGptStep", "TorchTemporalStep", "sample_code_maps"]


class TorchTemporalStep(DeviceCache):
    """HiFiGPT.temporal_step with numpy in and out (the cache: t2m.families.gpt.sampling.DeviceCache)."""

    def __init__(self, model: HiFiGPT, device: torch.device | str | None = None) -> None:
        super().__init__(device)
        self.model = model
        self.depth = model.config.depth

    def empty_cache(self, batch: int) -> Any:
        return self.cache_out(self.model.empty_cache("temporal", batch, self.device))

    @torch.no_grad()
    def __call__(self, cond: np.ndarray, codes: np.ndarray, position: int, length: np.ndarray,
                 past: Any) -> tuple[np.ndarray, np.ndarray, Any]:
        lengths = on_device(length, self.device) if self.model.config.length_conditioning else None
        context, stop, present = self.model.temporal_step(on_device(cond, self.device), on_device(codes, self.device),
                                                          position, lengths, self.cache_in(past))
        return context.cpu().numpy(), stop.cpu().numpy(), self.cache_out(present)


class TorchResidualGptStep(DeviceCache):
    """HiFiGPT.residual_step with numpy in and out (the cache: DeviceCache)."""

    def __init__(self, model: HiFiGPT, device: torch.device | str | None = None) -> None:
        super().__init__(device)
        self.model = model

    def empty_cache(self, batch: int) -> Any:
        return self.cache_out(self.model.empty_cache("residual", batch, self.device))

    @torch.no_grad()
    def __call__(self, context: np.ndarray, code: np.ndarray, depth: int, past: Any) -> tuple[np.ndarray, Any]:
        logits, present = self.model.residual_step(on_device(context, self.device), on_device(code, self.device),
                                                   depth, self.cache_in(past))
        return logits.cpu().numpy(), self.cache_out(present)


def sample_code_maps(model: HiFiGPT, cond: torch.Tensor | np.ndarray, target_tokens: Sequence[int | None],
                     guidance: float = 1.0, temperature: float = 1.0, top_k: int | None = None,
                     rng: np.random.Generator | int | None = None, greedy: bool = False) -> list[np.ndarray]:
    """One code map [steps, R] per condition row (cond [B, Dt]); target_tokens[i] steps for row i, None = free length
    (the stop head decides). temperature 0 or greedy=True picks the argmax and stops when the stop logit is > 0."""
    c = model.config
    job = reference_job(cond, target_tokens, c.max_tokens, guidance, temperature, top_k, rng, greedy)
    with evaluating(model):
        return only_job(sample_code_rows(TorchTemporalStep(model), TorchResidualGptStep(model), [job],
                                         c.max_tokens))
