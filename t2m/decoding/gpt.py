"""The GPT family's loop: every segment of every request in a batch steps in lockstep through one KV-cached step.

Each segment is its own sequence (condition token, then its codes), so all rows of a batch are always at the same
position and one `position` serves them all. Per segment there is a cond row and, when guidance != 1, a null row
(zero condition), combined as uncond + s * (cond - uncond). A segment with a target token count has End masked until
the target and stops at it; a free segment stops when it samples End (never as its first token) or at max_tokens.
Finished rows leave the cache so that a long segment does not make the short ones pay. Randomness comes from each
request's own numpy Generator, one uniform per active segment per step, segments in request order. A job's
`progress` sees its codes after every step (the service streams frames from them).

A `GptCohort` is one such batch: `sample_codes` runs one to its end; the service's continuous batching steps several
cohorts that started at different step boundaries side by side, each reporting a job the moment it is finished.

`GptStep` is what the loop needs from a network: the service wraps gpt_step.onnx, the PyTorch reference wraps
MotionGPT.forward_step; both take and return numpy arrays.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Protocol

import numpy as np

from t2m.decoding.lockstep import (
    Batch,
    Rows,
    SamplingJob,
    Segment,
    check_targets,
    drop_finished,
    guided,
    live_segments,
    report_progress,
    results,
    row_maps,
    start,
)
from t2m.decoding.tokens import sample_tokens

__all__ = ["GptCohort", "GptStep", "SamplingJob", "sample_codes"]


class GptStep(Protocol):
    """One autoregressive step for a batch of rows, with an explicit key/value cache."""

    def empty_cache(self, batch: int) -> np.ndarray: ...

    def __call__(self, cond: np.ndarray, token: np.ndarray, position: int, length: np.ndarray,
                 past: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(cond [B, Dt], previous token [B], position, length [B], past) -> (logits [B, V+1], present)."""
        ...


def _choose(job: SamplingJob, active: list[int], logits: np.ndarray, rows: Rows, batch: Batch,
            end_id: int) -> np.ndarray:
    """The next token of each active segment of one job: guided logits, End rule, one draw each."""
    # End is never a first token, and never before a segment's target
    mask_end = np.asarray([batch.segments[s].target is not None or not batch.segments[s].tokens for s in active])
    return sample_tokens(guided(job, active, logits, rows), mask_end, end_id, job.temperature, job.top_k, job.rng,
                         greedy=job.greedy)


def _advance(segment: Segment, token: int, end_id: int, max_tokens: int) -> None:
    if token == end_id:
        segment.done = True
        return
    segment.tokens.append(token)
    segment.reached(max_tokens)


class GptCohort:
    """Jobs that start at one step boundary and step together until each is done.

    The step graph takes one `position` for all its rows and a past of one length, so rows can share a call only if
    they started together: a cohort is such a group. Rows leave as their segments finish; a job is reported by
    `finished` as soon as all its segments are done (or it was cancelled), not when the whole cohort is. Continuous
    batching (t2m.service) runs several cohorts of different ages side by side, one call each per step boundary;
    `sample_codes` runs one cohort to its end.
    """

    def __init__(self, step: GptStep, jobs: Sequence[SamplingJob], max_tokens: int, end_id: int) -> None:
        check_targets(jobs, max_tokens)
        self.step, self.jobs, self.max_tokens, self.end_id = step, jobs, max_tokens, end_id
        self.batch = start(jobs, step.empty_cache)
        self.cancelled = [False] * len(jobs)
        self.position = 0                      # the next step's position: steps taken so far
        self._reported = [False] * len(jobs)

    @property
    def rows(self) -> int:
        """Rows (segments x cond/null) still stepping."""
        return len(self.batch.owner)

    @property
    def done(self) -> bool:
        return not len(self.batch.owner)

    def advance(self, on_step: Callable[[int], None] | None = None) -> None:
        """One network call for every live row, then one token for each of their segments."""
        batch = self.batch
        tokens_in = np.asarray([(batch.segments[s].tokens or [0])[-1] for s in batch.owner], dtype=np.int64)
        logits, batch.past = self.step(batch.cond, tokens_in, self.position, batch.length, batch.past)
        if on_step is not None:
            on_step(len(batch.owner))
        rows = row_maps(batch.owner)
        for job, active in live_segments(batch, self.jobs, self.cancelled):
            for s, token in zip(active, _choose(job, active, logits, rows, batch, self.end_id).tolist()):
                _advance(batch.segments[s], token, self.end_id, self.max_tokens)
            report_progress(batch, job, active)
        drop_finished(batch)
        self.position += 1

    def finished(self) -> list[tuple[int, list[np.ndarray] | None]]:
        """Jobs finished since the last call, in job order: (index, its segments' codes, or None if cancelled)."""
        out = []
        for j, indices in enumerate(self.batch.of_job):
            if self._reported[j] or not all(self.batch.segments[s].done for s in indices):
                continue
            self._reported[j] = True
            out.append((j, None if self.cancelled[j] else
                        [np.asarray(self.batch.segments[s].tokens, dtype=np.int64) for s in indices]))
        return out


def sample_codes(step: GptStep, jobs: Sequence[SamplingJob], max_tokens: int, end_id: int,
                 on_step: Callable[[int], None] | None = None) -> list[list[np.ndarray] | None]:
    """Generate the codes of every segment of every job; per job a list of int64 code arrays (one per segment, in
    order), or None for a job cancelled on the way. `on_step(rows)` is called after each network call."""
    cohort = GptCohort(step, jobs, max_tokens, end_id)
    while not cohort.done:
        cohort.advance(on_step)
    return results(cohort.batch, cohort.cancelled)
