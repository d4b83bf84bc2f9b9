"""T2M-HiFiGPT's loop: a temporal step per time step, then the residual GPT's R depth steps, every segment of every
request in lockstep (t2m.decoding.lockstep: cond rows, null rows for guidance, finished rows leave the batch).

At time position p the temporal step reads the condition token (p = 0) or the codes of step p, and returns the
context h_p and a stop logit. A free segment that has at least one step stops after p steps with probability
sigmoid(g / temperature), g = the guided stop logit u + s (c - u) (the paper's eq. 16 applied to the stop logits);
greedy: g > 0. A segment with a target never stops before it and ends at it; none goes past max_tokens. The segments
that go on then run the residual GPT from h_p with a fresh small cache: at depth d it returns logits for code d
(guided like the stop, then temperature, top-k and one draw), and the drawn code feeds depth d + 1. The null rows are
fed the guided choices, as in the GPT family.

Per request and position the random draws are: one uniform per free segment with a step (stop), then per depth one
uniform per going segment, segments in request order; so a request's codes depend only on its own generator. A
job's `progress` sees its segments' code rows after every position (the service streams frames from them).
A `HiFiGPTCohort` (a lockstep.Cohort) is one such batch; the service's continuous batching steps several side by
side, as for the GPT family. `TemporalStep` and `ResidualGptStep` are what the loop needs from the networks: the
service wraps temporal_step.onnx / residual_step.onnx, the PyTorch reference wraps HiFiGPT's step methods.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np

from t2m.decoding import lockstep
from t2m.decoding.lockstep import SamplingJob
from t2m.decoding.tokens import draw_stops

__all__ = ["HiFiGPTCohort", "ResidualGptStep", "SamplingJob", "TemporalStep", "depth_loop", "sample_code_rows"]


class TemporalStep(Protocol):
    """The temporal GPT, one position with its KV cache (a numpy array or the step's handle to one on a device; a
    step may have `keep_rows(past, keep)`, see t2m.decoding.lockstep.keep_rows)."""

    depth: int

    def empty_cache(self, batch: int) -> Any: ...

    def __call__(self, cond: np.ndarray, codes: np.ndarray, position: int, length: np.ndarray,
                 past: Any) -> tuple[np.ndarray, np.ndarray, Any]:
        """(cond [B, Dt], codes of step `position` [B, R], position, length [B], past) -> (context [B, E], stop logit
        [B], present)."""
        ...


class ResidualGptStep(Protocol):
    """The residual GPT, one depth with its own KV cache (fresh at every time step; numpy or the step's handle)."""

    def empty_cache(self, batch: int) -> Any: ...

    def __call__(self, context: np.ndarray, code: np.ndarray, depth: int,
                 past: Any) -> tuple[np.ndarray, Any]:
        """(context [B, E], code of depth - 1 [B], depth, past) -> (logits [B, K], present)."""
        ...


class HiFiGPTCohort(lockstep.Cohort):
    """T2M-HiFiGPT jobs stepping together from one step boundary (lockstep.Cohort): per time step one temporal call,
    then the residual GPT's R depth calls for the segments that go on."""

    def __init__(self, temporal: TemporalStep, residual: ResidualGptStep, jobs: Sequence[SamplingJob],
                 max_tokens: int) -> None:
        super().__init__(jobs, max_tokens, temporal.empty_cache)
        self.temporal, self.residual, self.depth = temporal, residual, temporal.depth

    def advance(self, on_step: Callable[[int], None] | None = None) -> None:
        """The stop decisions of this position, then the code rows of the segments that go on."""
        batch, depth = self.batch, self.depth
        codes_in = np.stack([(batch.segments[s].tokens or [np.zeros(depth, np.int64)])[-1] for s in batch.owner])
        context, stop, batch.past = self.temporal(batch.cond, codes_in, self.position, batch.length, batch.past)
        if on_step is not None:
            on_step(len(batch.owner))
        rows = lockstep.row_maps(batch.owner)
        live = []
        for job, active in lockstep.live_segments(batch, self.jobs, self.cancelled):
            free = [s for s in active if batch.segments[s].target is None and batch.segments[s].tokens]
            if free:
                guided = lockstep.guided(job, free, stop[:, None], rows)[:, 0]
                stops = draw_stops(guided, job.temperature, job.rng, job.greedy)
                for s, stopped in zip(free, stops):
                    batch.segments[s].done = bool(stopped)
            live.append((job, active))
        context = context[lockstep.drop_finished(batch, self.temporal)]
        if len(batch.owner):
            going = [(job, kept) for job, active in live if (kept := [s for s in active if not batch.segments[s].done])]
            for s, row in depth_loop(self.residual, context, going, batch.owner, depth, on_step).items():
                batch.segments[s].tokens.append(row)
                batch.segments[s].reached(self.max_tokens)
            lockstep.drop_finished(batch, self.temporal)
        for job, active in live:
            lockstep.report_progress(batch, job, active)
        self.position += 1


def sample_code_rows(temporal: TemporalStep, residual: ResidualGptStep, jobs: Sequence[SamplingJob],
                     max_tokens: int, on_step: Callable[[int], None] | None = None) -> list[list[np.ndarray] | None]:
    """Per job, one int64 code map [steps, R] per segment (in order), or None for a job cancelled on the way.
    `on_step(rows)` is called after each network call."""
    return HiFiGPTCohort(temporal, residual, jobs, max_tokens).run(on_step)


def depth_loop(residual: ResidualGptStep, context: np.ndarray, going: list[tuple[SamplingJob, list[int]]],
                owner: np.ndarray, depth: int, on_step: Callable[[int], None] | None) -> dict[int, np.ndarray]:
    """The R codes of this time step for every going segment (rows = `owner`, contexts in row order)."""
    rows = lockstep.row_maps(owner)
    chosen = {s: np.zeros(depth, dtype=np.int64) for _, active in going for s in active}
    past = residual.empty_cache(len(owner))
    code_in = np.zeros(len(owner), dtype=np.int64)
    for d in range(depth):
        logits, past = residual(context, code_in, d, past)
        if on_step is not None:
            on_step(len(owner))
        for (_, active), drawn in zip(going, lockstep.draw_for_jobs(logits, rows, going)):
            for s, code in zip(active, drawn):
                chosen[s][d] = code
        code_in = np.asarray([chosen[int(s)][d] for s in owner], dtype=np.int64)
    return chosen
