"""OpenAI CLIP's text tower, written out in one page (nanoGPT style), with OpenAI's parameter names.

T2M-GPT, MoMask and MoGenTS condition on ``clip_model.encode_text(clip.tokenize(text, truncate=True))`` of
OpenAI's CLIP ViT-B/32, cast to float32 and NOT normalised. This module computes exactly that:

    x = token_embedding(ids) + positional_embedding[:L]
    x = resblocks(x)        each: x + attn(ln_1(x)) with a causal mask, then x + mlp(ln_2(x)),
                            mlp = c_proj(QuickGELU(c_fc(.))), QuickGELU(x) = x * sigmoid(1.702 x)
    x = ln_final(x)
    features = x[the end-of-text position, i.e. argmax of ids] @ text_projection

QuickGELU is what OpenAI trained with; open_clip's plain ``ViT-B-32`` configuration uses nn.GELU instead, so
features differ (tests/model/test_clip_reference.py shows both facts against open_clip). The parameter names are
OpenAI's, so the text keys of ``ViT-B-32.pt`` load strictly (``t2m.model.networks.clip_weights``); sizes come from
the weights (:class:`ClipTextConfig`).
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn


@dataclass(frozen=True)
class ClipTextConfig:
    """Sizes of the text tower (defaults: OpenAI's ViT-B/32). Heads are width / 64 in every OpenAI CLIP."""

    vocab_size: int = 49408
    context_length: int = 77
    width: int = 512
    layers: int = 12
    heads: int = 8
    embed_dim: int = 512


class QuickGELU(nn.Module):
    """OpenAI CLIP's activation: x * sigmoid(1.702 x) (a fast approximation of GELU; not the same function)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x * torch.sigmoid(1.702 * x)


class CausalSelfAttention(nn.Module):
    """Multi-head self-attention stored as nn.MultiheadAttention stores it: one packed q/k/v projection
    (``in_proj_weight`` [3W, W], rows q then k then v) and ``out_proj``."""

    def __init__(self, width: int, heads: int) -> None:
        super().__init__()
        self.heads = heads
        self.in_proj_weight = nn.Parameter(torch.empty(3 * width, width))
        self.in_proj_bias = nn.Parameter(torch.zeros(3 * width))
        self.out_proj = nn.Linear(width, width)
        nn.init.normal_(self.in_proj_weight, std=width**-0.5)

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        batch, length, width = x.shape
        head_dim = width // self.heads
        q, k, v = F.linear(x, self.in_proj_weight, self.in_proj_bias).chunk(3, dim=-1)
        q, k, v = (t.reshape(batch, length, self.heads, head_dim).transpose(1, 2) for t in (q, k, v))
        scores = (q @ k.transpose(-2, -1)) * head_dim**-0.5 + mask  # mask: 0 on and below the diagonal, -inf above
        out = scores.softmax(dim=-1) @ v
        return self.out_proj(out.transpose(1, 2).reshape(batch, length, width))


class Mlp(nn.Module):
    def __init__(self, width: int) -> None:
        super().__init__()
        self.c_fc = nn.Linear(width, 4 * width)
        self.gelu = QuickGELU()
        self.c_proj = nn.Linear(4 * width, width)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.c_proj(self.gelu(self.c_fc(x)))


class ResidualAttentionBlock(nn.Module):
    """Pre-LayerNorm transformer block: x + attn(ln_1(x)), then x + mlp(ln_2(x))."""

    def __init__(self, width: int, heads: int) -> None:
        super().__init__()
        self.ln_1 = nn.LayerNorm(width)
        self.attn = CausalSelfAttention(width, heads)
        self.ln_2 = nn.LayerNorm(width)
        self.mlp = Mlp(width)

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        x = x + self.attn(self.ln_1(x), mask)
        return x + self.mlp(self.ln_2(x))


class Transformer(nn.Module):
    """Holds the blocks under ``resblocks`` so the keys read ``transformer.resblocks.{i}...`` as in OpenAI's file."""

    def __init__(self, width: int, layers: int, heads: int) -> None:
        super().__init__()
        self.resblocks = nn.ModuleList(ResidualAttentionBlock(width, heads) for _ in range(layers))

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        for block in self.resblocks:
            x = block(x, mask)
        return x


class ClipTextTransformer(nn.Module):
    """CLIP's text tower: token ids [B, L] (L <= context_length) -> ``encode_text`` features [B, embed_dim]."""

    causal_mask: torch.Tensor

    def __init__(self, config: ClipTextConfig) -> None:
        super().__init__()
        if config.width % config.heads:
            raise ValueError(f"CLIP text width {config.width} is not divisible by {config.heads} heads")
        self.config = config
        self.token_embedding = nn.Embedding(config.vocab_size, config.width)
        self.positional_embedding = nn.Parameter(torch.zeros(config.context_length, config.width))
        self.transformer = Transformer(config.width, config.layers, config.heads)
        self.ln_final = nn.LayerNorm(config.width)
        self.text_projection = nn.Parameter(torch.empty(config.width, config.embed_dim))
        nn.init.normal_(self.text_projection, std=config.width**-0.5)
        # not a weight: OpenAI's file has no such key, so it stays out of the state dict
        causal = torch.full((config.context_length, config.context_length), float("-inf")).triu(1)
        self.register_buffer("causal_mask", causal, persistent=False)

    def encode_text(self, input_ids: torch.Tensor) -> torch.Tensor:
        """OpenAI's encode_text: features at the end-of-text token (the largest id in each row), not normalised."""
        length = input_ids.shape[1]
        x = self.token_embedding(input_ids) + self.positional_embedding[:length]
        x = self.transformer(x, self.causal_mask[:length, :length])
        x = self.ln_final(x)
        end_of_text = input_ids.argmax(dim=-1)  # first position holding the largest id, as torch and ONNX ArgMax agree
        pooled = x[torch.arange(x.shape[0]), end_of_text]
        return pooled @ self.text_projection

    def forward(self, input_ids: torch.Tensor, attention_mask: torch.Tensor | None = None) -> torch.Tensor:
        """The text graph's signature (input_ids, attention_mask); the mask is not needed: the causal attention
        never lets the end-of-text position see the padding after it."""
        return self.encode_text(input_ids)
