"""Reference (PyTorch) decoding of the masked family: the recipe an exported graph + a numpy loop must reproduce.

1. :func:`generate_base`: MaskGIT-style confidence re-masking of the first layer. All tokens start masked; before
   step n of N the ``remask_counts`` least confident tokens are masked again (t2m.model.masking) and predicted;
   a token's confidence is the guided probability of the code drawn for it, and a token left alone in a step is
   frozen from then on (MoMask's rule).
2. :func:`generate_residual`: layers 1..R-1, one forward pass each; a drawn pad id means "layer unused" (-1).

Guidance: the condition and the null condition (zeros) run as one batch of 2B rows;
logits = uncond + s (cond - uncond). Then top-k (keep the k largest logits), temperature, a categorical draw
with the given generator. Rows past a motion's length are -1 in the output.

``forward`` replaces the model's own forward pass (same arguments and result), so the very same loop can drive an
exported graph (t2m.export.onnx_masked checks the tokens agree).
"""
from __future__ import annotations

import math
from collections.abc import Callable

import torch

from t2m.model.networks.masked_transformer import MaskedTransformer
from t2m.model.networks.residual_transformer import ResidualTransformer


def guided_logits(forward, cond: torch.Tensor, guidance: float, *inputs: torch.Tensor) -> torch.Tensor:
    """forward(cond, *inputs) once on [cond; zeros] (inputs doubled) -> uncond + s (cond - uncond); s = 1: cond only."""
    if guidance == 1.0:
        return forward(cond, *inputs)
    doubled = [torch.cat([x, x]) for x in inputs]
    logits = forward(torch.cat([cond, torch.zeros_like(cond)]), *doubled)
    conditional, unconditional = logits.chunk(2)
    return unconditional + guidance * (conditional - unconditional)


def draw(
    logits: torch.Tensor, top_k: int | None, temperature: float, generator: torch.Generator | None
) -> torch.Tensor:
    """A categorical draw over the last axis after top-k and temperature; returns int64 of logits.shape[:-1]."""
    if temperature <= 0:
        raise ValueError(f"temperature must be > 0, got {temperature}")
    if top_k is not None and top_k < logits.shape[-1]:
        kth = logits.topk(top_k, dim=-1).values[..., -1:]
        logits = logits.masked_fill(logits < kth, float("-inf"))
    probs = torch.softmax(logits / temperature, dim=-1)
    flat = torch.multinomial(probs.reshape(-1, probs.shape[-1]), 1, generator=generator)
    return flat.view(logits.shape[:-1])


def remask_count_tensor(length: torch.Tensor, columns: int, step: int, steps: int) -> torch.Tensor:
    """Per motion: tokens to (re)mask before ``step`` (float32 as t2m.model.masking.remask_counts)."""
    tau = torch.linspace(0, 1, steps)[step]
    ratio = torch.cos(tau * math.pi * 0.5)
    return torch.round(ratio * (length * columns).float()).clamp(min=1).long()


@torch.no_grad()
def generate_base(
    model: MaskedTransformer,
    cond: torch.Tensor,
    length: torch.Tensor,
    steps: int = 10,
    guidance: float = 4.0,
    top_k: int | None = None,
    temperature: float = 1.0,
    generator: torch.Generator | None = None,
    forward: Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor] | None = None,
) -> torch.Tensor:
    """First-layer token maps [B, max(length), C] for texts cond [B, Dt] and row counts length [B] (>= 1)."""
    if steps < 1 or int(length.min()) < 1:
        raise ValueError(f"need steps >= 1 and every length >= 1, got steps={steps}, lengths={length.tolist()}")
    model.eval()
    forward = forward or model
    c = model.config
    batch, rows = len(length), int(length.max())
    real = model.valid_rows(length, rows)[:, :, None].expand(batch, rows, c.columns).reshape(batch, -1)
    tokens = torch.full((batch, rows * c.columns), c.mask_id, dtype=torch.long)
    scores = torch.zeros(batch, rows * c.columns).masked_fill(~real, float("inf"))  # padding is never masked
    for step in range(steps):
        counts = remask_count_tensor(length, c.columns, step, steps)
        masked = scores.argsort(dim=1).argsort(dim=1) < counts[:, None]
        tokens = torch.where(masked, torch.full_like(tokens, c.mask_id), tokens)
        logits = guided_logits(lambda cond_, tokens_, length_: forward(tokens_, cond_, length_), cond, guidance,
                               tokens.view(batch, rows, c.columns), length)
        logits = logits.reshape(batch, rows * c.columns, -1)
        drawn = draw(logits, top_k, temperature, generator)
        tokens = torch.where(masked, drawn, tokens)
        confidence = torch.softmax(logits, dim=-1).gather(-1, drawn[..., None])[..., 0]
        scores = torch.where(masked, confidence, torch.full_like(confidence, float("inf")))
    return torch.where(real, tokens, torch.full_like(tokens, -1)).view(batch, rows, c.columns)


@torch.no_grad()
def generate_residual(
    model: ResidualTransformer,
    base: torch.Tensor,
    cond: torch.Tensor,
    length: torch.Tensor,
    guidance: float = 5.0,
    top_k: int | None = None,
    temperature: float = 1.0,
    generator: torch.Generator | None = None,
    forward: Callable[[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor] | None = None,
) -> torch.Tensor:
    """Layers 1..R-1 on top of base [B, T, C]: codes [B, T, C, R] (-1 = unused layer or past the length)."""
    model.eval()
    forward = forward or model
    batch, rows, columns = base.shape
    layers = model.config.residual_layers
    codes = torch.full((batch, rows, columns, layers), -1, dtype=torch.long)
    codes[..., 0] = base
    real = model.valid_rows(length, rows)[:, :, None]
    for q in range(1, layers):
        layer = torch.full((batch,), q, dtype=torch.long)
        logits = guided_logits(lambda cond_, codes_, layer_, length_: forward(codes_, layer_, cond_, length_), cond,
                               guidance, codes, layer, length)
        drawn = draw(logits, top_k, temperature, generator)
        codes[..., q] = torch.where(real & (drawn != model.pad_id), drawn, torch.full_like(drawn, -1))
    return codes
