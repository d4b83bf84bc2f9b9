"""The GPT sampling loop: every segment of every request in a batch steps in lockstep through one KV-cached graph.

Each segment is its own sequence (condition token, then its codes), so all rows of a batch are always at the same
position and one `position` input serves them all. Per segment there is a cond row and, when guidance != 1, a null
row (zero condition); the two are combined as uncond + s * (cond - uncond). A segment with a target token count has
End masked until the target and stops at it (End forced); a free segment stops when it samples End (never as its first
token) or at max_tokens. Finished rows are dropped from the cache so that a long segment does not make the short
ones pay. Randomness comes from each request's own numpy Generator, drawn in a fixed order (one uniform per segment
per step, segments in request order), so a request's codes do not depend on what else shares its batch.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import onnxruntime as ort

__all__ = ["GptStep", "SamplingJob", "sample_codes", "sample_tokens"]


@dataclass
class SamplingJob:
    """One request's segments in a lockstep batch."""

    conds: np.ndarray                   # float32 [S, Dt] text features, one row per segment
    targets: Sequence[int | None]       # code tokens per segment; None = free length (stop on End)
    guidance: float
    temperature: float
    top_k: int | None
    rng: np.random.Generator
    cancelled: Callable[[], bool] = field(default=lambda: False)


class GptStep:
    """One call of gpt_step.onnx: (cond, token, position, length, past_kv) -> (logits, present_kv)."""

    def __init__(self, session: ort.InferenceSession, n_layer: int, n_head: int, head_dim: int,
                 has_length_input: bool) -> None:
        self.session = session
        self.n_layer, self.n_head, self.head_dim = n_layer, n_head, head_dim
        self.has_length_input = has_length_input

    def empty_cache(self, batch: int) -> np.ndarray:
        return np.zeros((self.n_layer, 2, batch, self.n_head, 0, self.head_dim), dtype=np.float32)

    def __call__(self, cond: np.ndarray, token: np.ndarray, position: int, length: np.ndarray,
                 past: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        feeds = {"cond": cond, "token": token, "position": np.asarray([position], dtype=np.int64), "past_kv": past}
        if self.has_length_input:
            feeds["length"] = length
        logits, present = self.session.run(["logits", "present_kv"], feeds)
        return logits, present


def sample_tokens(logits: np.ndarray, mask_end: np.ndarray, end_id: int, temperature: float, top_k: int | None,
                  rng: np.random.Generator) -> np.ndarray:
    """Draw one class per row of `logits` [S, V+1] with End masked where `mask_end`; one uniform per row."""
    logits = np.array(logits, dtype=np.float64)
    logits[mask_end, end_id] = -np.inf
    logits /= temperature
    if top_k is not None and top_k < logits.shape[1]:
        kth_largest = np.partition(logits, -top_k, axis=1)[:, -top_k, None]
        logits[logits < kth_largest] = -np.inf
    logits -= logits.max(axis=1, keepdims=True)
    probs = np.exp(logits)
    cdf = np.cumsum(probs, axis=1)
    draws = rng.random(len(logits)) * cdf[:, -1]
    choice = (cdf <= draws[:, None]).sum(axis=1)                  # first index whose cdf exceeds the draw
    return np.minimum(choice, logits.shape[1] - 1).astype(np.int64)


@dataclass
class _Slot:
    """One segment being generated: which job, its target, its tokens so far and its rows in the batch."""

    job: int
    target: int | None
    tokens: list[int] = field(default_factory=list)
    done: bool = False


def sample_codes(step: GptStep, jobs: Sequence[SamplingJob], max_tokens: int, end_id: int,
                 on_step: Callable[[int], None] | None = None) -> list[list[np.ndarray] | None]:
    """Generate the codes of every segment of every job; None for a job cancelled on the way.

    `on_step(rows)` is called after each graph run (for metrics). Returns per job a list of int64 code arrays,
    one per segment, in order.
    """
    slots: list[_Slot] = []
    job_slots: list[list[int]] = []
    cond_rows, lengths, row_slot = [], [], []
    for j, job in enumerate(jobs):
        job_slots.append([])
        for s, target in enumerate(job.targets):
            if target is not None and not 1 <= target <= max_tokens:
                raise ValueError(f"segment {s}: target of {target} tokens is outside 1..{max_tokens}")
            index = len(slots)
            slots.append(_Slot(job=j, target=target))
            job_slots[j].append(index)
            cond_rows.append(job.conds[s])
            lengths.append(target or 0)
            row_slot.append(index)
    # null rows (zero condition) for the guided jobs, after all cond rows
    dim = jobs[0].conds.shape[1] if jobs else 0
    for index, slot in enumerate(slots):
        if jobs[slot.job].guidance != 1.0:
            cond_rows.append(np.zeros(dim, dtype=np.float32))
            lengths.append(slot.target or 0)
            row_slot.append(index)

    cond = np.asarray(cond_rows, dtype=np.float32).reshape(len(cond_rows), dim)
    length = np.asarray(lengths, dtype=np.int64)
    rows = np.asarray(row_slot, dtype=np.int64)          # batch row -> slot
    past = step.empty_cache(len(rows))
    results: list[list[np.ndarray] | None] = [[] for _ in jobs]

    position = 0
    while len(rows):
        tokens_in = np.asarray([slots[s].tokens[-1] if slots[s].tokens else 0 for s in rows], dtype=np.int64)
        logits, past = step(cond, tokens_in, position, length, past)
        if on_step is not None:
            on_step(len(rows))
        row_of = {int(s): r for r, s in reversed(list(enumerate(rows)))}   # slot -> its cond row (first)
        uncond_at = {int(s): r for r, s in enumerate(rows) if r != row_of[int(s)]}
        for j, job in enumerate(jobs):
            active = [s for s in job_slots[j] if not slots[s].done]
            if not active:
                continue
            if job.cancelled():
                results[j] = None
                for s in job_slots[j]:
                    slots[s].done = True
                continue
            cond_logits = logits[[row_of[s] for s in active]].astype(np.float64)
            if job.guidance != 1.0:
                null_logits = logits[[uncond_at[s] for s in active]].astype(np.float64)
                cond_logits = null_logits + job.guidance * (cond_logits - null_logits)
            mask_end = np.asarray([slots[s].target is not None or not slots[s].tokens for s in active])
            drawn = sample_tokens(cond_logits, mask_end, end_id, job.temperature, job.top_k, job.rng)
            for s, token in zip(active, drawn.tolist()):
                slot = slots[s]
                if token == end_id:
                    slot.done = True
                    continue
                slot.tokens.append(token)
                if len(slot.tokens) == (slot.target if slot.target is not None else max_tokens):
                    slot.done = True
        keep = np.asarray([not slots[s].done for s in rows])
        if not keep.all():
            rows, cond, length, past = rows[keep], cond[keep], length[keep], past[:, :, keep]
        position += 1

    for j, job_result in enumerate(results):
        if job_result is not None:
            job_result.extend(np.asarray(slots[s].tokens, dtype=np.int64) for s in job_slots[j])
    return results
