"""The text condition as every token model trains on it (T2M-GPT, T2M-HiFiGPT, the masked family): its size, the
text encoder's length, and the two regularisers of the paper recipes, condition noise and condition dropout (the
null condition that classifier-free guidance samples against)."""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import torch


def perturb_condition(cond: torch.Tensor, max_noise: float, generator: torch.Generator | None = None) -> torch.Tensor:
    """Add isotropic noise of relative size U[0, max_noise] per row, keeping each row's norm (null rows stay zero)."""
    import torch

    if max_noise == 0:
        return cond
    norm = cond.norm(dim=-1, keepdim=True)
    scale = torch.rand(cond.shape[0], 1, generator=generator) * max_noise
    noise = torch.randn(cond.shape, generator=generator) * norm * scale / cond.shape[-1] ** 0.5
    noisy = cond + noise
    return noisy * norm / noisy.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def drop_condition(cond: torch.Tensor, p: float, generator: torch.Generator | None = None) -> torch.Tensor:
    """Zero each row's text feature with probability p (the null condition)."""
    import torch

    keep = torch.rand(cond.shape[0], generator=generator) >= p
    return cond * keep[:, None].to(cond.dtype)


def text_features_dim(features: dict[str, np.ndarray]) -> int:
    if not features:
        raise ValueError("no caption features: the dataset has no captions")
    return int(next(iter(features.values())).shape[-1])


def encoder_max_length(name: str) -> int:
    from t2m.model.networks.text_encoders import MINILM_MAX_LENGTH

    return MINILM_MAX_LENGTH if name == "minilm" else 77
