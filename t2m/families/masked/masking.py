"""The cosine masking schedule of the masked token models, for training and for sampling.

gamma(tau) = cos(pi tau / 2) is the fraction of tokens masked (MaskGIT; MoMask; MoGenTS eq. 5).

- Training draws tau ~ U(0, 1) per motion and masks by MoGenTS's temporal-spatial rule (paper section 3.4): first
  ``max(1, round(gamma * length))`` whole frames (token rows), then ``round(gamma * C)`` random tokens in every other
  real frame. Sampling starts from a fully masked map, so the model must see whole masked frames often; masking
  single tokens only would almost never show it one. With one column (MoMask's 1D tokens) only frames are masked.
- Masked tokens get BERT's treatment: 80% become the mask token, 10% a random code, 10% stay as they are.
- Sampling with N steps re-masks ``max(1, round(gamma(n / (N - 1)) * length * C))`` of the least confident tokens
  before step n, counted as torch does it in float32 (MoMask computes it so: a float64 count differs at exact
  halves for odd lengths).
- The residual transformer trains on layer q = round((1 - cos(pi u / 2)) (R - 2)) + 1, u ~ U(0, 1): q in 1..R-1,
  low layers more often (MoMask's q schedule).
"""
from __future__ import annotations

import math

import torch

from t2m.families.masked.loop import remask_counts as decoding_remask_counts


def mask_ratio(tau: torch.Tensor) -> torch.Tensor:
    """gamma(tau) = cos(pi tau / 2): 1 at tau = 0 (all masked), 0 at tau = 1."""
    return torch.cos(tau * math.pi * 0.5)


def remask_counts(length: int, steps: int, columns: int = 1) -> list[int]:
    """Tokens masked before each of the ``steps`` sampling steps, for a map of ``length`` rows x ``columns`` (the
    decoding loop's own schedule, t2m.families.masked.loop.remask_counts)."""
    if steps < 1 or length < 1 or columns < 1:
        raise ValueError(f"steps, length and columns must be >= 1, got {steps}, {length}, {columns}")
    return decoding_remask_counts(length * columns, steps)


def _lowest(scores: torch.Tensor, counts: torch.Tensor) -> torch.Tensor:
    """True at the ``counts`` lowest scores along the last axis (counts broadcast against scores[..., 0])."""
    ranks = scores.argsort(dim=-1).argsort(dim=-1)
    return ranks < counts.unsqueeze(-1)


def temporal_spatial_mask(
    length: torch.Tensor,
    rows: int,
    columns: int,
    ratio: torch.Tensor,
    spatial: bool = True,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """Which tokens of a [B, rows, columns] map to mask for the per-motion ratios gamma [B] (see the module doc).

    length [B]: real rows (rows beyond it are never masked). Returns bool [B, rows, columns].
    """
    batch = length.shape[0]
    valid = torch.arange(rows)[None, :] < length[:, None]  # [B, T]
    frame_scores = torch.rand(batch, rows, generator=generator).masked_fill(~valid, 2.0)  # padding ranks last
    frame_counts = torch.round(ratio * length).clamp(min=1).long()
    frames = _lowest(frame_scores, frame_counts) & valid
    mask = frames[:, :, None].expand(batch, rows, columns)
    if spatial and columns > 1:
        token_counts = torch.round(ratio * columns).long()[:, None].expand(batch, rows)
        tokens = _lowest(torch.rand(batch, rows, columns, generator=generator), token_counts)
        mask = mask | (tokens & valid[:, :, None])
    return mask


def bert_replace(
    tokens: torch.Tensor,
    mask: torch.Tensor,
    codebook_size: int,
    mask_id: int,
    generator: torch.Generator | None = None,
    random_prob: float = 0.1,
    mask_prob: float = 0.8,
) -> torch.Tensor:
    """The model's input: masked tokens become mask_id (mask_prob), a random code (random_prob) or stay."""
    draw = torch.rand(tokens.shape, generator=generator)
    random_codes = torch.randint(0, codebook_size, tokens.shape, generator=generator)
    to_random = mask & (draw < random_prob)
    to_mask = mask & (draw >= random_prob) & (draw < random_prob + mask_prob)
    out = torch.where(to_random, random_codes, tokens)
    return torch.where(to_mask, torch.full_like(tokens, mask_id), out)


def residual_layer_schedule(batch: int, layers: int, generator: torch.Generator | None = None) -> torch.Tensor:
    """The RVQ layer (1..layers-1) each motion of a batch trains the residual transformer on; int64 [B]."""
    if layers < 2:
        raise ValueError(f"a residual stage needs at least 2 quantiser layers, got {layers}")
    u = torch.rand(batch, generator=generator)
    return (torch.round((1 - mask_ratio(u)) * (layers - 2)) + 1).long()
