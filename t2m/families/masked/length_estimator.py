"""Free length: a small classifier from the text feature to a number of token rows, sampled (MoMask's estimator).

A masked model needs the length before it starts (the GPT ends on its own End token instead). For a null duration
the service samples one: softmax over 0..max_tokens rows, drawn with the request's generator, so the same seed gives
the same length. Row counts below ``min_tokens`` are never drawn (MoMask can draw 0 and then attends over nothing).

Key names as MoMask's ``estimator``: ``output.{0,4,8,11}`` linear layers, ``output.{1,5,9}`` LayerNorms.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass

import torch
from torch import nn

from t2m.model.networks.config import ConfigDict


@dataclass
class LengthEstimatorConfig(ConfigDict):
    """MoMask: text 512, hidden 512 (then 256, 128), 50 classes."""

    label = "length estimator"

    text_dim: int = 384
    hidden: int = 256
    max_tokens: int = 50
    dropout: float = 0.2

    def __post_init__(self) -> None:
        self._require_positive("text_dim", "hidden", "max_tokens")
        if self.hidden < 4:
            raise ValueError(f"hidden must be >= 4 (it is halved twice), got {self.hidden}")


class LengthEstimator(nn.Module):
    """cond [B, Dt] -> logits [B, max_tokens + 1] over token-row counts 0..max_tokens."""

    def __init__(self, config: LengthEstimatorConfig | None = None) -> None:
        super().__init__()
        self.config = c = config or LengthEstimatorConfig()
        sizes = [c.text_dim, c.hidden, c.hidden // 2, c.hidden // 4]
        layers: list[nn.Module] = []
        for size_in, size_out in itertools.pairwise(sizes):
            layers += [nn.Linear(size_in, size_out), nn.LayerNorm(size_out), nn.LeakyReLU(0.2), nn.Dropout(c.dropout)]
        layers[-1:] = [nn.Linear(sizes[-1], c.max_tokens + 1)]  # no dropout before the classifier
        self.output = nn.Sequential(*layers)

    def forward(self, cond: torch.Tensor) -> torch.Tensor:
        return self.output(cond)


def sample_length(
    logits: torch.Tensor, generator: torch.Generator | None = None, temperature: float = 1.0, min_tokens: int = 1
) -> torch.Tensor:
    """Draw a row count per row of logits [B, N] (classes below min_tokens excluded) -> int64 [B]."""
    if temperature <= 0:
        raise ValueError(f"temperature must be > 0, got {temperature}")
    logits = logits.detach().float() / temperature
    logits[:, :min_tokens] = float("-inf")
    return torch.multinomial(torch.softmax(logits, dim=-1), 1, generator=generator)[:, 0]
