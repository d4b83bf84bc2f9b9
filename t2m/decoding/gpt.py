"""The GPT family's loop: every segment of every request in a batch steps in lockstep through one KV-cached step.

Each segment is its own sequence (condition token, then its codes), so all rows of a batch are always at the same
position and one `position` serves them all. Per segment there is a cond row and, when guidance != 1, a null row
(zero condition), combined as uncond + s * (cond - uncond). A segment with a target token count has End masked until
the target and stops at it; a free segment stops when it samples End (never as its first token) or at max_tokens.
Finished rows leave the cache so that a long segment does not make the short ones pay. Randomness comes from each
request's own numpy Generator, one uniform per active segment per step, segments in request order. A job's
`progress` sees its codes after every step (the service streams frames from them).

`GptStep` is what the loop needs from a network: the service wraps gpt_step.onnx, the PyTorch reference wraps
MotionGPT.forward_step; both take and return numpy arrays.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from t2m.decoding.tokens import guided_logits, sample_tokens

__all__ = ["GptStep", "SamplingJob", "sample_codes"]


class GptStep(Protocol):
    """One autoregressive step for a batch of rows, with an explicit key/value cache."""

    def empty_cache(self, batch: int) -> np.ndarray: ...

    def __call__(self, cond: np.ndarray, token: np.ndarray, position: int, length: np.ndarray,
                 past: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(cond [B, Dt], previous token [B], position, length [B], past) -> (logits [B, V+1], present)."""
        ...


@dataclass
class SamplingJob:
    """One request's segments in a lockstep batch."""

    conds: np.ndarray                   # float32 [S, Dt] text features, one row per segment
    targets: Sequence[int | None]       # code tokens per segment; None = free length (stop on End)
    guidance: float
    temperature: float
    top_k: int | None
    rng: np.random.Generator
    greedy: bool = False
    cancelled: Callable[[], bool] = field(default=lambda: False)
    # after each step that gave the job codes: each segment's codes so far and whether it is finished (streaming)
    progress: Callable[[list[list[int]], list[bool]], None] | None = None


@dataclass
class _Segment:
    """One segment being generated: its job, its target and its tokens so far."""

    job: int
    target: int | None
    tokens: list[int] = field(default_factory=list)
    done: bool = False

    @property
    def last_token(self) -> int:
        return self.tokens[-1] if self.tokens else 0


@dataclass
class _Batch:
    """The rows stepping together: row r works for segment `owner[r]`; cond rows come first, null rows after."""

    segments: list[_Segment]
    of_job: list[list[int]]             # job -> its segments' indices
    cond: np.ndarray                    # float32 [rows, Dt]
    length: np.ndarray                  # int64 [rows]
    owner: np.ndarray                   # int64 [rows] -> segment index
    past: np.ndarray


def _check_targets(jobs: Sequence[SamplingJob], max_tokens: int) -> None:
    for job in jobs:
        for index, target in enumerate(job.targets):
            if target is not None and not 1 <= target <= max_tokens:
                raise ValueError(f"segment {index}: target of {target} tokens is outside 1..{max_tokens}")


def _start(step: GptStep, jobs: Sequence[SamplingJob]) -> _Batch:
    """One cond row per segment of every job, then one null row per segment of every guided job."""
    segments: list[_Segment] = []
    of_job: list[list[int]] = []
    conds: list[np.ndarray] = []
    for j, job in enumerate(jobs):
        of_job.append([])
        for s, target in enumerate(job.targets):
            of_job[j].append(len(segments))
            segments.append(_Segment(job=j, target=target))
            conds.append(job.conds[s])
    owners = list(range(len(segments)))
    dim = jobs[0].conds.shape[1] if jobs else 0
    for index, segment in enumerate(segments):
        if jobs[segment.job].guidance != 1.0:
            conds.append(np.zeros(dim, dtype=np.float32))
            owners.append(index)
    owner = np.asarray(owners, dtype=np.int64)
    length = np.asarray([segments[s].target or 0 for s in owner], dtype=np.int64)
    cond = np.asarray(conds, dtype=np.float32).reshape(len(owners), dim)
    return _Batch(segments, of_job, cond, length, owner, step.empty_cache(len(owner)))


def _choose(job: SamplingJob, active: list[int], logits: np.ndarray, cond_row: dict[int, int],
            null_row: dict[int, int], batch: _Batch, end_id: int) -> np.ndarray:
    """The next token of each active segment of one job: guided logits, End rule, one draw each."""
    chosen = logits[[cond_row[s] for s in active]].astype(np.float64)
    if job.guidance != 1.0:
        chosen = guided_logits(chosen, logits[[null_row[s] for s in active]].astype(np.float64), job.guidance)
    # End is never a first token, and never before a segment's target
    mask_end = np.asarray([batch.segments[s].target is not None or not batch.segments[s].tokens for s in active])
    return sample_tokens(chosen, mask_end, end_id, job.temperature, job.top_k, job.rng, greedy=job.greedy)


def _advance(segment: _Segment, token: int, end_id: int, max_tokens: int) -> None:
    if token == end_id:
        segment.done = True
        return
    segment.tokens.append(token)
    if len(segment.tokens) == (segment.target if segment.target is not None else max_tokens):
        segment.done = True


def _drop_finished(batch: _Batch) -> None:
    keep = np.asarray([not batch.segments[s].done for s in batch.owner], dtype=bool)
    if not keep.all():
        batch.owner, batch.cond, batch.length = batch.owner[keep], batch.cond[keep], batch.length[keep]
        batch.past = batch.past[:, :, keep]


def sample_codes(step: GptStep, jobs: Sequence[SamplingJob], max_tokens: int, end_id: int,
                 on_step: Callable[[int], None] | None = None) -> list[list[np.ndarray] | None]:
    """Generate the codes of every segment of every job; per job a list of int64 code arrays (one per segment, in
    order), or None for a job cancelled on the way. `on_step(rows)` is called after each network call."""
    _check_targets(jobs, max_tokens)
    batch = _start(step, jobs)
    cancelled = [False] * len(jobs)
    position = 0
    while len(batch.owner):
        tokens_in = np.asarray([batch.segments[s].last_token for s in batch.owner], dtype=np.int64)
        logits, batch.past = step(batch.cond, tokens_in, position, batch.length, batch.past)
        if on_step is not None:
            on_step(len(batch.owner))
        cond_row = {int(s): r for r, s in reversed(list(enumerate(batch.owner)))}   # first row of each segment
        null_row = {int(s): r for r, s in enumerate(batch.owner) if r != cond_row[int(s)]}
        for j, job in enumerate(jobs):
            active = [s for s in batch.of_job[j] if not batch.segments[s].done]
            if not active:
                continue
            if job.cancelled():
                cancelled[j] = True
                for s in batch.of_job[j]:
                    batch.segments[s].done = True
                continue
            for s, token in zip(active, _choose(job, active, logits, cond_row, null_row, batch, end_id).tolist()):
                _advance(batch.segments[s], token, end_id, max_tokens)
            if job.progress is not None:
                mine = [batch.segments[s] for s in batch.of_job[j]]
                job.progress([segment.tokens for segment in mine], [segment.done for segment in mine])
        _drop_finished(batch)
        position += 1
    return [None if cancelled[j] else [np.asarray(batch.segments[s].tokens, dtype=np.int64) for s in indices]
            for j, indices in enumerate(batch.of_job)]
