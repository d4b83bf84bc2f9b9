"""MotionGPT's step over a key/value cache of fixed capacity: the form a CUDA graph can replay.

Why: `MotionGPT.forward_step` grows its cache by one position per step (a Concat), so every step has new shapes
and new buffers, and a GPU replays nothing: each of a step's ~500 kernels is launched from the host, which is what
bounds the release-size step at 3.1-3.6 ms on an H100 (docs/gpu.md). Here the cache always holds `capacity`
positions; a step writes its new key/value at each row's `position` (an elementwise select, no shape change) and
attends to the positions up to it (a key mask), so consecutive steps have the same shapes, and onnxruntime can
capture a step once and replay it (`enable_cuda_graph`, t2m/runtime/graphed_step.py).

Every reshape uses constants (-1 for the batch), so the exported graph has no shape arithmetic on the batch; each
row has its own position, so rows need not be in lockstep. The masked positions add exact zeros to the softmax and
to the weighted sum of values, so the logits equal `forward_step`'s up to the order of float additions
(tests/service/test_graphed_step.py).
"""
from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from t2m.families.gpt.network import Block, CausalSelfAttention, MotionGPT

__all__ = ["empty_fixed_cache", "fixed_cache_step"]


def empty_fixed_cache(gpt: MotionGPT, batch: int, capacity: int | None = None) -> torch.Tensor:
    """[n_layer, 2, B, H, capacity, hd] zeros; capacity defaults to block_size (every position a segment can use)."""
    c = gpt.config
    return torch.zeros(c.n_layer, 2, batch, c.n_head, capacity or c.block_size, c.head_dim)


def _heads(attention: CausalSelfAttention, x: torch.Tensor) -> torch.Tensor:
    """[B, 1, E] -> [B, H, 1, hd], with constant reshape sizes. One position per row, so splitting the heads is a
    reshape alone: the transpose that a sequence would need moves a dimension of size 1, which changes no element's
    place but is a kernel on a GPU (4 per layer, 72 per release-size step)."""
    return x.reshape(-1, attention.n_head, 1, attention.head_dim)


def _attention_step(attention: CausalSelfAttention, x: torch.Tensor, cache_k: torch.Tensor, cache_v: torch.Tensor,
                    write: torch.Tensor, visible: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """x [B, 1, E]; caches [B, H, C, hd]; write [B, 1, C, 1] (the row's position); visible [B, 1, 1, C]
    (positions <= the row's) -> (y [B, 1, E], k, v with this step's key/value written)."""
    k = torch.where(write, _heads(attention, attention.key(x)), cache_k)
    v = torch.where(write, _heads(attention, attention.value(x)), cache_v)
    q = _heads(attention, attention.query(x))
    scores = (q @ k.transpose(-2, -1)) * (1.0 / math.sqrt(attention.head_dim))
    weights = F.softmax(scores.masked_fill(~visible, float("-inf")), dim=-1)
    y = (weights @ v).reshape(-1, 1, attention.n_head * attention.head_dim)   # [B, H, 1, hd]: heads joined as above
    return attention.proj(y), k, v


def _block_step(block: Block, x: torch.Tensor, cache_k: torch.Tensor, cache_v: torch.Tensor, write: torch.Tensor,
                visible: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    y, k, v = _attention_step(block.attn, block.ln1(x), cache_k, cache_v, write, visible)
    x = x + y
    return x + block.mlp(block.ln2(x)), k, v


def fixed_cache_step(gpt: MotionGPT, cond: torch.Tensor, token: torch.Tensor, position: torch.Tensor,
                     length: torch.Tensor | None, cache: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """One step of every row at its own position.

    cond [B, Dt]; token [B] (the previous token, a code; ignored where position is 0); position [B] int64, below the
    cache's capacity; length [B] | None; cache [n_layer, 2, B, H, C, hd] -> (logits [B, K+1], the cache with each
    row's key/value written at its position). Positions above a row's are neither read nor changed.
    """
    base = gpt.trans_base
    slots = torch.arange(int(cache.shape[4]), dtype=torch.long)   # int(): a constant in the exported graph
    write = (slots.view(1, 1, -1, 1) == position.view(-1, 1, 1, 1))          # [B, 1, C, 1]
    visible = (slots.view(1, 1, 1, -1) <= position.view(-1, 1, 1, 1))        # [B, 1, 1, C]
    cond_x = base.condition_token(cond, length)
    token_x = base.tok_emb(token)   # the loop's tokens are codes (< K); no Clip on int64, which CUDA may lack
    x = torch.where((position == 0).view(-1, 1), cond_x, token_x)
    x = base.drop(x + base.pos_embed.table().index_select(0, position)).unsqueeze(1)
    present = []
    for index, block in enumerate(gpt.blocks()):
        x, k, v = _block_step(block, x, cache[index, 0], cache[index, 1], write, visible)
        present.append(torch.stack([k, v]))
    logits = gpt.trans_head.head(gpt.trans_head.ln_f(x)).reshape(-1, gpt.config.codebook_size + 1)
    return logits, torch.stack(present)
