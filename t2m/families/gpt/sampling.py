"""The PyTorch reference sampler: MotionGPT.forward_step as the step of the shared GPT loop (t2m.families.gpt.loop).

The service runs the same loop over gpt_step.onnx, so the recipe (guidance, the End rule, temperature, top-k, one
uniform draw per segment per step from a numpy Generator) is written once; for the same seed the reference and the
service choose the same codes whenever their logits agree.
"""
from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import Any

import numpy as np
import torch

from t2m.families.gpt.loop import SamplingJob
from t2m.families.gpt.loop import sample_codes as run_gpt_loop
from t2m.families.gpt.network import MotionGPT

__all__ = ["DeviceCache", "TorchGptStep", "evaluating", "on_device", "only_job", "reference_job", "sample_codes"]


def on_device(array: np.ndarray, device: torch.device | None) -> torch.Tensor:
    """A numpy input as a tensor, on `device` when one is given."""
    tensor = torch.from_numpy(np.ascontiguousarray(array))
    return tensor if device is None else tensor.to(device)


class DeviceCache:
    """Where a reference step keeps its cache: a float32 numpy array between steps (no device, the parity tests),
    or a tensor left on `device` (the GPU benchmark: only what the sampler reads comes back to the host), with
    `keep_rows` (t2m.decoding.lockstep.keep_rows) slicing it where it is."""

    def __init__(self, device: torch.device | str | None) -> None:
        self.device = None if device is None else torch.device(device)

    def cache_in(self, past: Any) -> torch.Tensor:
        return on_device(past, self.device) if isinstance(past, np.ndarray) else past

    def cache_out(self, present: torch.Tensor) -> Any:
        return present.numpy() if self.device is None else present

    def keep_rows(self, past: Any, keep: np.ndarray) -> Any:
        if isinstance(past, np.ndarray):
            return past[:, :, keep]
        return past[:, :, torch.from_numpy(keep).to(past.device)]


class TorchGptStep(DeviceCache):
    """MotionGPT.forward_step with numpy in and out (the cache: DeviceCache)."""

    def __init__(self, gpt: MotionGPT, device: torch.device | str | None = None) -> None:
        super().__init__(device)
        self.gpt = gpt

    def empty_cache(self, batch: int) -> Any:
        return self.cache_out(self.gpt.empty_cache(batch, self.device))

    @torch.no_grad()
    def __call__(self, cond: np.ndarray, token: np.ndarray, position: int, length: np.ndarray,
                 past: Any) -> tuple[np.ndarray, Any]:
        lengths = (on_device(length, self.device) if self.gpt.config.length_conditioning else
                   torch.zeros(len(length), dtype=torch.long, device=self.device))
        logits, present = self.gpt.forward_step(on_device(cond, self.device), on_device(token, self.device),
                                                position, lengths, self.cache_in(past))
        return logits.cpu().numpy(), self.cache_out(present)


def reference_job(cond: torch.Tensor | np.ndarray, target_tokens: Sequence[int | None], max_tokens: int,
                  guidance: float, temperature: float, top_k: int | None, rng: np.random.Generator | int | None,
                  greedy: bool) -> SamplingJob:
    """Every condition row as one segment of one request (the reference samplers' job); temperature 0 = greedy."""
    conds = np.asarray(cond.detach().cpu().numpy() if isinstance(cond, torch.Tensor) else cond, dtype=np.float32)
    return SamplingJob.of(conds, target_tokens, max_tokens=max_tokens, guidance=guidance, temperature=temperature,
                          top_k=top_k, rng=rng, greedy=greedy)


@contextmanager
def evaluating(module: torch.nn.Module) -> Iterator[None]:
    """The module in eval mode for the block, then back to the mode it had."""
    was_training = module.training
    module.eval()
    try:
        yield
    finally:
        module.train(was_training)


def only_job(results: list[list[np.ndarray] | None]) -> list[np.ndarray]:
    """The one job's segments (a job without a cancel callback is never cancelled)."""
    (codes,) = results
    if codes is None:  # pragma: no cover
        raise RuntimeError("the reference sampler's job was cancelled")
    return codes


def sample_codes(gpt: MotionGPT, cond: torch.Tensor | np.ndarray, target_tokens: Sequence[int | None],
                 guidance: float = 1.0, temperature: float = 1.0, top_k: int | None = None,
                 rng: np.random.Generator | int | None = None, greedy: bool = False) -> list[list[int]]:
    """One code sequence per condition row (cond [B, Dt]); target_tokens[i] codes for row i, None = free length
    (stop on End). temperature 0 or greedy=True picks the argmax. Returns B lists of code ids (< codebook size)."""
    config = gpt.config
    job = reference_job(cond, target_tokens, config.max_tokens, guidance, temperature, top_k, rng, greedy)
    with evaluating(gpt):
        codes = only_job(run_gpt_loop(TorchGptStep(gpt), [job], config.max_tokens, config.end_id))
    return [row.tolist() for row in codes]
