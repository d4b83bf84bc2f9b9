"""The PyTorch reference of the diffusion family: the official DDPM loop written again in torch over the modules.

Unlike the other families' references, this one does not step the shared numpy loop (t2m.families.diffusion.loop): it
is an independent second reading of the facts (docs: ../shared/docs/diffusion-models.md §3.2, §3.3, §5.2, §6),
shaped like the official code (one request of B rows, the conditional and the unconditional forward as two calls,
tensors in float32 with float64 tables cast per step), so that the numpy loop over any denoiser can be checked
against it with injected noise. :class:`TorchDenoiser` is the other direction: a module as the numpy loop's
denoiser.
"""
from __future__ import annotations

import math
from collections.abc import Iterator, Sequence

import numpy as np
import torch

from t2m.families.diffusion.network import MDM

__all__ = ["TorchDenoiser", "reference_chain", "reference_sample", "reference_tables"]


class TorchDenoiser:
    """MDM.forward with numpy in and out: the t2m.families.diffusion.loop.Denoiser of a module."""

    def __init__(self, model: MDM) -> None:
        self.model = model.eval()

    @torch.no_grad()
    def __call__(self, x_t: np.ndarray, t: np.ndarray, text: np.ndarray, text_mask: np.ndarray | None,
                 length: np.ndarray, prefix: np.ndarray | None) -> np.ndarray:
        def tensor(array: np.ndarray | None) -> torch.Tensor | None:
            return None if array is None else torch.from_numpy(np.ascontiguousarray(array))

        out = self.model(tensor(x_t), tensor(t), tensor(text), tensor(text_mask), tensor(length), tensor(prefix))
        return out.numpy()


def reference_tables(steps: int) -> dict[str, torch.Tensor]:
    """float64 tables of the cosine schedule, as the official respacing wrapper leaves them (every step kept,
    betas re-derived from the cumulative product)."""
    def alpha_bar(s: float) -> float:
        return math.cos((s + 0.008) / 1.008 * math.pi / 2) ** 2

    raw = torch.tensor([min(1 - alpha_bar((i + 1) / steps) / alpha_bar(i / steps), 0.999) for i in range(steps)],
                       dtype=torch.float64)
    raw_bar = torch.cumprod(1 - raw, dim=0)
    betas = 1 - raw_bar / torch.cat([torch.ones(1, dtype=torch.float64), raw_bar[:-1]])
    alpha_bar_t = torch.cumprod(1 - betas, dim=0)
    alpha_bar_prev = torch.cat([torch.ones(1, dtype=torch.float64), alpha_bar_t[:-1]])
    variance = betas * (1 - alpha_bar_prev) / (1 - alpha_bar_t)
    return {
        "coef1": betas * alpha_bar_prev.sqrt() / (1 - alpha_bar_t),
        "coef2": (1 - alpha_bar_prev) * (1 - betas).sqrt() / (1 - alpha_bar_t),
        "log_variance": torch.cat([variance[1:2], variance[1:]]).log(),
    }


def _noise(noise: Iterator[torch.Tensor] | None, shape: tuple[int, ...],
           generator: torch.Generator | None) -> torch.Tensor:
    if noise is None:
        return torch.randn(shape, generator=generator)
    return next(noise).reshape(shape).float()


@torch.no_grad()
def reference_sample(model: MDM, text: torch.Tensor, frames: int, *, guidance: float = 1.0,
                     text_mask: torch.Tensor | None = None, prefix: torch.Tensor | None = None,
                     known: torch.Tensor | None = None, known_mask: torch.Tensor | None = None,
                     noise: Iterator[torch.Tensor] | None = None,
                     generator: torch.Generator | None = None) -> torch.Tensor:
    """x0 [B, frames, F] of one request (B rows of one length) after the model's trained number of steps.

    noise: x_T then one tensor per step, [B, frames, F] each (the official order); else drawn from `generator`.
    known / known_mask [B, frames, F]: MDM's editing, written over each step's (guided) x0 prediction.
    """
    model.eval()
    tables = reference_tables(model.config.diffusion_steps)
    rows = text.shape[0]
    shape = (rows, frames, model.config.features)
    length = torch.full((rows,), frames, dtype=torch.long)
    scale = torch.tensor(guidance, dtype=torch.float32)
    x = _noise(noise, shape, generator)
    for step in reversed(range(model.config.diffusion_steps)):
        t = torch.full((rows,), step, dtype=torch.long)
        x0 = model(x, t, text, text_mask, length, prefix)
        if guidance != 1.0:
            x0_uncond = model(x, t, torch.zeros_like(text), text_mask, length, prefix)
            x0 = x0_uncond + scale * (x0 - x0_uncond)
        if known is not None and known_mask is not None:
            x0 = x0 * ~known_mask + known * known_mask
        coef1, coef2 = tables["coef1"][step].float(), tables["coef2"][step].float()
        mean = coef1 * x0 + coef2 * x
        nonzero = torch.tensor(float(step != 0))
        x = mean + nonzero * torch.exp(0.5 * tables["log_variance"][step].float()) * _noise(noise, shape, generator)
    return x


@torch.no_grad()
def reference_chain(model: MDM, texts: Sequence[torch.Tensor], prefix: torch.Tensor, frames: int, *,
                    guidance: float = 1.0, text_masks: Sequence[torch.Tensor] | None = None,
                    noise: Iterator[torch.Tensor] | None = None,
                    generator: torch.Generator | None = None) -> torch.Tensor:
    """DiP's autoregressive sampling of one request: ⌈frames / pred_len⌉ calls of `reference_sample`, call i with
    texts[i] (or the last), each after the previous call's last context_len frames; [B, frames, F]."""
    pred_len, context_len = model.config.pred_len, model.config.context_len
    calls = frames // pred_len + int(frames % pred_len > 0)
    made = []
    for call in range(calls):
        index = min(call, len(texts) - 1)
        new = reference_sample(model, texts[index], pred_len, guidance=guidance, prefix=prefix,
                               text_mask=None if text_masks is None else text_masks[index], noise=noise,
                               generator=generator)
        made.append(new)
        prefix = new[:, -context_len:]
    return torch.cat(made, dim=1)[:, :frames]
