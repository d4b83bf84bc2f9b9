"""Picking the next token from logits: guidance, End masking, temperature, top-k, one uniform draw per row.

Each row takes exactly one `rng.random()` draw per step (none when greedy), so a request's choices depend only on
its own generator and its own logits, not on which other rows share its batch.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["RowRule", "RowRules", "draw_stops", "draw_tokens", "draw_tokens_of_jobs", "guide_in_place", "guided_logits",
           "sample_tokens",
           "stop_probability"]


def guided_logits(cond: np.ndarray, uncond: np.ndarray, scale: float | np.ndarray) -> np.ndarray:
    """Classifier-free guidance: uncond + s * (cond - uncond) (s a number, or one per row as [N, 1])."""
    return uncond + scale * (cond - uncond)


def guide_in_place(cond: np.ndarray, uncond: np.ndarray, scale: float | np.ndarray) -> np.ndarray:
    """guided_logits written over `cond` (a float64 array the caller owns): the same three operations in the same
    order, so the same bits (IEEE sums and products commute), without the three temporaries a large batch's draws
    would allocate."""
    np.subtract(cond, uncond, out=cond)
    np.multiply(cond, scale, out=cond)
    np.add(cond, uncond, out=cond)
    return cond


def draw_tokens(logits: np.ndarray, temperature: float, top_k: int | None, rng: np.random.Generator,
                greedy: bool = False, only: np.ndarray | None = None) -> np.ndarray:
    """One class per row of `logits` [N, V]: the argmax when `greedy`, else a draw from softmax(logits / temperature)
    restricted to the top_k classes, by the inverse CDF of one uniform per row (drawn in row order).

    `only` (a boolean mask over M >= N rows): `logits` holds the rows where it is true, and their classes are the
    ones a draw over all M rows would give them; the generator still takes a uniform for every one of the M rows,
    so what it draws next is unchanged (the masked family's mask stage keeps only the re-masked tokens' draws, so it
    computes only theirs)."""
    uniforms = None if greedy else rng.random(len(logits) if only is None else len(only))
    if only is not None and uniforms is not None:
        uniforms = uniforms[only]
    return RowRules([RowRule(len(logits), temperature, top_k, rng, greedy)]).draw(logits, uniforms)


def _pick(shifted: np.ndarray, uniforms: np.ndarray, filtered: bool) -> np.ndarray:
    """The inverse-CDF choice per row of float64 logits shifted to a maximum of 0 (-inf where filtered out), one
    uniform each: the first class whose cumulative exp exceeds uniform x total (the last class if none does).

    When a top-k filter left every row the same number c of classes (no ties at the k-th), the exp and the
    cumulative sum run over those c classes alone: the same partial sums (exp(-inf) adds an exact 0), so the same
    choice, for c/V of the work (MoMask's top-k keeps 52 of 513)."""
    width = shifted.shape[1]
    if filtered and len(shifted):
        kept = shifted > -np.inf
        counts = kept.sum(axis=1)
        count = int(counts[0])
        if count < width and (counts == count).all():
            flat = np.flatnonzero(kept)                                       # kept classes, in class order
            columns = (flat % width).reshape(len(shifted), count)
            cdf = np.cumsum(np.exp(shifted.ravel()[flat].reshape(len(shifted), count)), axis=1)
            first = (cdf <= (uniforms * cdf[:, -1])[:, None]).sum(axis=1)
            picked = columns[np.arange(len(shifted)), np.minimum(first, count - 1)]
            return np.where(first < count, picked, width - 1).astype(np.int64)
    cdf = np.cumsum(np.exp(shifted), axis=1)
    choice = (cdf <= (uniforms * cdf[:, -1])[:, None]).sum(axis=1)      # first index whose cdf exceeds the draw
    return np.minimum(choice, width - 1).astype(np.int64)


@dataclass(frozen=True)
class RowRule:
    """How `rows` consecutive rows of a batched draw pick their class: one request's options and its generator."""

    rows: int
    temperature: float
    top_k: int | None
    rng: np.random.Generator
    greedy: bool = False


class RowRules:
    """`RowRule`s made into per-row arrays once, for one or many batched draws over the same rows (T2M-HiFiGPT draws
    R times per time step for the same segments, t2m.decoding.lockstep.DrawPlan)."""

    def __init__(self, rules: Sequence[RowRule]) -> None:
        self.rules = list(rules)
        self.rows = sum(rule.rows for rule in self.rules)
        self.greedy = np.array([rule.greedy for rule in self.rules for _ in range(rule.rows)], dtype=bool)
        self.drawn_rules = [rule for rule in self.rules if not rule.greedy]
        temperatures = [rule.temperature for rule in self.drawn_rules]
        self.temperature = (np.array([t for rule, t in zip(self.drawn_rules, temperatures)
                                      for _ in range(rule.rows)])[:, None]
                            if any(t != 1.0 for t in temperatures) else None)
        self.top_ks = np.array([rule.top_k or 0 for rule in self.drawn_rules for _ in range(rule.rows)])
        self.top_k_values = sorted(set(self.top_ks.tolist()) - {0})

    def uniforms(self, draws: int) -> np.ndarray | None:
        """The uniforms of `draws` draws at once, [draws, drawn rows] (None when every row is greedy): row d is what
        the d-th draw would take, as numpy's Generator gives a block of n doubles as n single draws would."""
        if not self.drawn_rules:
            return None
        return np.concatenate([rule.rng.random(rule.rows * draws).reshape(draws, rule.rows)
                               for rule in self.drawn_rules], axis=1)

    def draw(self, logits: np.ndarray, uniforms: np.ndarray | None = None, owned: bool = False) -> np.ndarray:
        """One class per row of `logits` [N, V] (N = the rules' rows): see draw_tokens_of_jobs. `uniforms`: this
        draw's row of `uniforms(draws)`, drawn ahead; by default each rule's generator draws now. `owned`: `logits`
        is a float64 array the caller hands over, worked on in place instead of copied."""
        if not (owned and logits.dtype == np.float64):
            logits = np.array(logits, dtype=np.float64)
        choice = np.zeros(len(logits), dtype=np.int64)
        greedy = self.greedy
        if greedy.any():
            choice[greedy] = logits[greedy].argmax(axis=1)
            logits = logits[~greedy]
        if not self.drawn_rules:
            return choice
        if self.temperature is not None:
            logits /= self.temperature
        for top_k in self.top_k_values:
            if top_k < logits.shape[1]:
                chosen = self.top_ks == top_k
                mine = logits[chosen]
                kth_largest = np.partition(mine, -top_k, axis=1)[:, -top_k, None]
                mine[mine < kth_largest] = -np.inf
                logits[chosen] = mine
        logits -= logits.max(axis=1, keepdims=True)
        if uniforms is None:
            uniforms = np.concatenate([rule.rng.random(rule.rows) for rule in self.drawn_rules])
        choice[~greedy] = _pick(logits, uniforms, filtered=bool(self.top_k_values))
        return choice


def draw_tokens_of_jobs(logits: np.ndarray, rules: Sequence[RowRule]) -> np.ndarray:
    """`draw_tokens` for many requests at once: the rows of `logits` [N, V] belong to `rules` in order. The same
    numbers, row for row, as one `draw_tokens` call per request (the same float64 operations per row, and each
    request's uniforms drawn from its own generator in row order); one pass of numpy instead of one per request,
    which is what a step of many requests on a CPU pays for."""
    return RowRules(rules).draw(logits)


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
