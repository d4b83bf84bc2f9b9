"""The GPT family's loop: every segment of every request in a batch steps in lockstep through one KV-cached step.

Each segment is its own sequence (condition token, then its codes), so all rows of a batch are always at the same
position and one `position` serves them all. Per segment there is a cond row and, when guidance != 1, a null row
(zero condition), combined as uncond + s * (cond - uncond). A segment with a target token count has End masked until
the target and stops at it; a free segment stops when it samples End (never as its first token) or at max_tokens.
Finished rows leave the cache so that a long segment does not make the short ones pay. Randomness comes from each
request's own numpy Generator, one uniform per active segment per step, segments in request order. A job's
`progress` sees its codes after every step (the service streams frames from them).

A `GptCohort` (a lockstep.Cohort) is one such batch: `sample_codes` runs one to its end; the service's continuous
batching steps several cohorts that started at different step boundaries side by side, each reporting a job the
moment it is finished.

`GptStep` is what the loop needs from a network: the service wraps gpt_step.onnx, the PyTorch reference wraps
MotionGPT.forward_step; both take and return numpy arrays.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np

from t2m.decoding.lockstep import (
    Cohort,
    SamplingJob,
    Segment,
    draw_for_jobs,
    drop_finished,
    live_segments,
    report_progress,
    row_maps,
)

__all__ = ["GptCohort", "GptStep", "SamplingJob", "sample_codes"]


class GptStep(Protocol):
    """One autoregressive step for a batch of rows, with an explicit key/value cache. The cache is whatever the step
    returns (a numpy array, or a handle to one on a device); a step may also have `keep_rows(past, keep)`
    (t2m.decoding.lockstep.keep_rows: the numpy default slices the batch axis)."""

    def empty_cache(self, batch: int) -> Any: ...

    def __call__(self, cond: np.ndarray, token: np.ndarray, position: int, length: np.ndarray,
                 past: Any) -> tuple[np.ndarray, Any]:
        """(cond [B, Dt], previous token [B], position, length [B], past) -> (logits [B, V+1], present)."""
        ...


def _advance(segment: Segment, token: int, end_id: int, max_tokens: int) -> None:
    if token == end_id:
        segment.done = True
        return
    segment.tokens.append(token)
    segment.reached(max_tokens)


class GptCohort(Cohort):
    """GPT jobs stepping together from one step boundary (lockstep.Cohort): one gpt_step call per time step."""

    def __init__(self, step: GptStep, jobs: Sequence[SamplingJob], max_tokens: int, end_id: int) -> None:
        super().__init__(jobs, max_tokens, step.empty_cache)
        self.step, self.end_id = step, end_id

    def advance(self, on_step: Callable[[int], None] | None = None) -> None:
        """One network call for every live row, then one token for each of their segments."""
        batch = self.batch
        tokens_in = np.asarray([(batch.segments[s].tokens or [0])[-1] for s in batch.owner], dtype=np.int64)
        logits, batch.past = self.step(batch.cond, tokens_in, self.position, batch.length, batch.past)
        if on_step is not None:
            on_step(len(batch.owner))
        going = list(live_segments(batch, self.jobs, self.cancelled))
        # End is never a first token, and never before a segment's target
        no_end = [batch.segments[s].target is not None or not batch.segments[s].tokens
                  for _, active in going for s in active]
        drawn = draw_for_jobs(logits, row_maps(batch.owner), going, forbid=(np.asarray(no_end), self.end_id))
        for (job, active), tokens in zip(going, drawn):
            for s, token in zip(active, tokens.tolist()):
                _advance(batch.segments[s], token, self.end_id, self.max_tokens)
            report_progress(batch, job, active)
        drop_finished(batch, self.step)
        self.position += 1


def sample_codes(step: GptStep, jobs: Sequence[SamplingJob], max_tokens: int, end_id: int,
                 on_step: Callable[[int], None] | None = None) -> list[list[np.ndarray] | None]:
    """Generate the codes of every segment of every job; per job a list of int64 code arrays (one per segment, in
    order), or None for a job cancelled on the way. `on_step(rows)` is called after each network call."""
    return GptCohort(step, jobs, max_tokens, end_id).run(on_step)
