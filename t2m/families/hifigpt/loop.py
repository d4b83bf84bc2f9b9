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
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from t2m.decoding import lockstep
from t2m.decoding.lockstep import SamplingJob
from t2m.decoding.tokens import draw_stops

__all__ = ["HiFiGPTCohort", "ResidualGptStep", "SamplingJob", "TemporalStep", "advance_together", "depth_loop",
           "sample_code_rows"]


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
        advance_together([self], on_step)

    @classmethod
    def advance_together(cls, cohorts: Sequence[lockstep.Cohort], on_step: Callable[[int], None] | None = None) -> None:
        mine = [cohort for cohort in cohorts if isinstance(cohort, HiFiGPTCohort)]
        if len(mine) != len(cohorts):
            raise TypeError("T2M-HiFiGPT cohorts step together only with T2M-HiFiGPT cohorts")
        advance_together(mine, on_step)

    def _stops(self, on_step: Callable[[int], None] | None) -> _DepthWork:
        """The temporal call of this position and the stop draws: what the residual GPT has to do next."""
        batch, depth = self.batch, self.depth
        codes_in = np.stack([(batch.segments[s].tokens or [np.zeros(depth, np.int64)])[-1] for s in batch.owner])
        context, stop, batch.past = self.temporal(batch.cond, codes_in, self.position, batch.length, batch.past)
        if on_step is not None:
            on_step(len(batch.owner))
        rows = None          # worked out only when a free segment draws its stop (timed segments never do)
        live = []
        for job, active in lockstep.live_segments(batch, self.jobs, self.cancelled):
            free = [s for s in active if batch.segments[s].target is None and batch.segments[s].tokens]
            if free:
                rows = rows or lockstep.row_maps(batch.owner)
                guided = lockstep.guided(job, free, stop[:, None], rows)[:, 0]
                stops = draw_stops(guided, job.temperature, job.rng, job.greedy)
                for s, stopped in zip(free, stops):
                    batch.segments[s].done = bool(stopped)
            live.append((job, active))
        context = context[lockstep.drop_finished(batch, self.temporal)]
        going = [(job, kept) for job, active in live if (kept := [s for s in active if not batch.segments[s].done])]
        return _DepthWork(self, context, going, batch.owner.copy(), live)

    def _codes(self, work: _DepthWork, chosen: dict[int, np.ndarray]) -> None:
        """This position's code rows (segment -> R codes) appended; finished rows leave; progress reported."""
        batch = self.batch
        if len(work.owner):
            for s, row in chosen.items():
                batch.segments[s].tokens.append(row)
                batch.segments[s].reached(self.max_tokens)
            lockstep.drop_finished(batch, self.temporal)
        for job, active in work.live:
            lockstep.report_progress(batch, job, active)
        self.position += 1


@dataclass
class _DepthWork:
    """One cohort's share of a position's residual GPT calls: its going rows' contexts, in its row order."""

    cohort: HiFiGPTCohort
    context: np.ndarray
    going: list[tuple[SamplingJob, list[int]]]
    owner: np.ndarray
    live: list[tuple[SamplingJob, list[int]]]


def advance_together(cohorts: Sequence[HiFiGPTCohort], on_step: Callable[[int], None] | None = None) -> None:
    """One time step of each cohort: their temporal calls one by one (each has its own position and cache length),
    then the residual GPT's R depth calls once for all their going rows (its cache is fresh at every time step, so
    rows of any position can share it). Each job draws from its own generator in the same order as alone (its stops,
    then its depths), and every row's logits are its own (the step graphs are row-independent), so a cohort's codes
    are the same stepped alone or together."""
    if any(cohort.residual is not cohorts[0].residual for cohort in cohorts):
        raise ValueError("cohorts share residual calls only when they step the same residual GPT")
    works = [cohort._stops(on_step) for cohort in cohorts]
    shared = [work for work in works if len(work.owner)]
    chosen: dict[int, dict[int, np.ndarray]] = {id(work): {} for work in works}
    if shared:   # segment ids made unique across cohorts by an offset each
        offsets = np.cumsum([0] + [len(work.cohort.batch.segments) for work in shared[:-1]]).tolist()
        context = np.concatenate([work.context for work in shared])
        owner = np.concatenate([work.owner + offset for work, offset in zip(shared, offsets)])
        going = [(job, [s + offset for s in segments]) for work, offset in zip(shared, offsets)
                 for job, segments in work.going]
        codes = depth_loop(shared[0].cohort.residual, context, going, owner, shared[0].cohort.depth, on_step)
        for work, offset in zip(shared, offsets):
            end = offset + len(work.cohort.batch.segments)
            chosen[id(work)] = {s - offset: row for s, row in codes.items() if offset <= s < end}
    for cohort, work in zip(cohorts, works):
        cohort._codes(work, chosen[id(work)])


def sample_code_rows(temporal: TemporalStep, residual: ResidualGptStep, jobs: Sequence[SamplingJob],
                     max_tokens: int, on_step: Callable[[int], None] | None = None) -> list[list[np.ndarray] | None]:
    """Per job, one int64 code map [steps, R] per segment (in order), or None for a job cancelled on the way.
    `on_step(rows)` is called after each network call."""
    return HiFiGPTCohort(temporal, residual, jobs, max_tokens).run(on_step)


def depth_loop(residual: ResidualGptStep, context: np.ndarray, going: list[tuple[SamplingJob, list[int]]],
               owner: np.ndarray, depth: int, on_step: Callable[[int], None] | None) -> dict[int, np.ndarray]:
    """The R codes of this time step for every going segment (rows = `owner`, contexts in row order). The R draws
    share one lockstep.DrawPlan: the same segments are drawn at every depth, and each job's R uniforms come from one
    call of its generator."""
    plan = lockstep.DrawPlan(lockstep.row_maps(owner), going, draws=depth)
    index = {s: i for i, s in enumerate(plan.segments)}
    row_segment = np.asarray([index[int(s)] for s in owner], dtype=np.intp)   # each row's segment, in plan order
    codes = np.zeros((len(plan.segments), depth), dtype=np.int64)
    past = residual.empty_cache(len(owner))
    code_in = np.zeros(len(owner), dtype=np.int64)
    for d in range(depth):
        logits, past = residual(context, code_in, d, past)
        if on_step is not None:
            on_step(len(owner))
        codes[:, d] = plan.draw(logits)
        code_in = codes[row_segment, d]
    return {s: codes[i] for i, s in enumerate(plan.segments)}
