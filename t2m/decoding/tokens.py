"""Picking the next token from logits: guidance, End masking, temperature, top-k, one uniform draw per row.

Each row takes exactly one `rng.random()` draw per step (none when greedy), so a request's choices depend only on
its own generator and its own logits, not on which other rows share its batch.
"""
from __future__ import annotations

import numpy as np

__all__ = ["draw_stops", "draw_tokens", "guided_logits", "sample_tokens", "stop_probability"]


def guided_logits(cond: np.ndarray, uncond: np.ndarray, scale: float) -> np.ndarray:
    """Classifier-free guidance: uncond + s * (cond - uncond); s = 1 gives the conditional logits."""
    return uncond + scale * (cond - uncond)


def draw_tokens(logits: np.ndarray, temperature: float, top_k: int | None, rng: np.random.Generator,
                greedy: bool = False) -> np.ndarray:
    """One class per row of `logits` [N, V]: the argmax when `greedy`, else a draw from softmax(logits / temperature)
    restricted to the top_k classes, by the inverse CDF of one uniform per row (drawn in row order)."""
    logits = np.array(logits, dtype=np.float64)
    if greedy:
        return logits.argmax(axis=1).astype(np.int64)
    logits /= temperature
    if top_k is not None and top_k < logits.shape[1]:
        kth_largest = np.partition(logits, -top_k, axis=1)[:, -top_k, None]
        logits[logits < kth_largest] = -np.inf
    logits -= logits.max(axis=1, keepdims=True)
    cdf = np.cumsum(np.exp(logits), axis=1)
    draws = rng.random(len(logits)) * cdf[:, -1]
    choice = (cdf <= draws[:, None]).sum(axis=1)                  # first index whose cdf exceeds the draw
    return np.minimum(choice, logits.shape[1] - 1).astype(np.int64)


def sample_tokens(logits: np.ndarray, mask_end: np.ndarray, end_id: int, temperature: float, top_k: int | None,
                  rng: np.random.Generator, greedy: bool = False) -> np.ndarray:
    """The GPT's choice: `draw_tokens` over logits [S, V+1] with End masked where `mask_end`."""
    logits = np.array(logits, dtype=np.float64)
    logits[mask_end, end_id] = -np.inf
    return draw_tokens(logits, temperature, top_k, rng, greedy)


def stop_probability(logits: np.ndarray, temperature: float = 1.0) -> np.ndarray:
    """P(stop now) from binary stop logits (already guided): sigmoid(logit / temperature), computed stably."""
    z = np.asarray(logits, dtype=np.float64) / temperature
    return np.exp(-np.logaddexp(0.0, -z))


def draw_stops(logits: np.ndarray, temperature: float, rng: np.random.Generator, greedy: bool = False) -> np.ndarray:
    """Stop or go for each row of binary stop logits [N] (T2M-HiFiGPT's stop head): a row stops when its one uniform
    falls below stop_probability (greedy: when the logit is > 0, no draw)."""
    logits = np.asarray(logits, dtype=np.float64)
    if greedy:
        return logits > 0
    return rng.random(len(logits)) < stop_probability(logits, temperature)
