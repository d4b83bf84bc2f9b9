"""Continuous batching of the autoregressive families (GPT, T2M-HiFiGPT): requests join the running work at a step
boundary and leave when done.

The step graphs (gpt_step.onnx, temporal_step.onnx) take one `position` for all their rows and a key/value past of
one length with no attention mask, so rows at different positions cannot share a call without changing their
logits. What the graphs allow exactly: the requests admitted at one boundary form a cohort (t2m.decoding.lockstep.
Cohort: GptCohort, HiFiGPTCohort) whose rows step together; cohorts of different ages run side by side, one call
each per step boundary (T2M-HiFiGPT: a temporal call each, then the residual GPT's R calls once for the rows of all
of them: that cache is fresh at every time step, so rows of any position share it); which of them step at a
boundary is the session's StepOrder's choice (engine/step_order.py: the shortest work first by default). Requests
admitted while the newest cohort has not stepped yet join it (nothing was computed for it, so it is the same as
starting together). A request leaves the step its last segment finishes, whatever is still running beside it, and is
decoded then (the service's batcher decodes it, and prepares requests that join mid-run, on a helper thread beside
the steps: t2m.runtime.scheduling.ContinuousBatcher). Its codes come from its own seeded generator and its own rows'
logits (int8 graphs quantise activations per row: t2m/export/writing/row_quantize.py), so they are the same alone,
in a run-to-completion batch, joined mid-run, in any step order, or sharing residual calls with other cohorts.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from t2m.decoding.lockstep import Cohort, SamplingJob
from t2m.runtime.step_order import ShortestFirst, StepOrder
from t2m.runtime.types import GenerationRequest, Motion, SteppingEngine

__all__ = ["CohortSource", "Finished", "PreparedJobs", "RunningCohorts", "Sampled"]

Finished = list[tuple[GenerationRequest, Motion | BaseException]]
"""Requests whose answer is ready, each with its Motion or the failure to raise in its place."""


@dataclass
class PreparedJobs:
    """Requests turned into sampling jobs: `jobs[i]` belongs to request `owners[i]` (with its warnings `notes[i]`);
    a request that failed before sampling has its error in `failures[index]`."""

    failures: list[BaseException | None]
    jobs: list = field(default_factory=list)
    owners: list[int] = field(default_factory=list)
    notes: list[list[str]] = field(default_factory=list)


@runtime_checkable
class CohortSource(Protocol):
    """A family's codes object that can start a cohort (GptCodes, HiFiGPTCodes)."""

    def cohort(self, jobs: Sequence[SamplingJob], max_tokens: int) -> Cohort: ...


@dataclass(frozen=True)
class Sampled:
    """A request whose codes are done (None: cancelled on the way), with its warnings: what `finish` decodes."""

    request: GenerationRequest
    codes: list[np.ndarray] | None
    notes: list[str]


@dataclass
class _Running:
    cohort: Cohort
    requests: list[GenerationRequest]
    notes: list[list[str]]
    skipped: int = 0        # boundaries in a row this cohort was passed over (the StepOrder's bound)


class RunningCohorts:
    """One worker's running work: `admit` requests at a step boundary, `advance` the cohorts `order` chooses."""

    def __init__(self, engine: SteppingEngine, codes: CohortSource, order: StepOrder | None = None) -> None:
        self.engine, self.codes = engine, codes
        self.order: StepOrder = order or ShortestFirst()
        self.running: list[_Running] = []
        self.steps = 0          # step boundaries passed (advance calls)
        self.joins_mid_run = 0  # requests admitted while another cohort was part-way through
        self.merged = 0         # requests that joined a cohort which had not stepped yet

    @property
    def rows(self) -> int:
        """Rows stepping now, over all cohorts (what the batcher's row budget counts)."""
        return sum(running.cohort.rows for running in self.running)

    @property
    def idle(self) -> bool:
        return not self.running

    def admit(self, requests: Sequence[GenerationRequest]) -> Finished:
        """Start `requests` as a new cohort at the next step; those failing before sampling are returned at once."""
        return self.admit_prepared(requests, self.engine.prepare(requests))

    def admit_prepared(self, requests: Sequence[GenerationRequest], prepared: PreparedJobs) -> Finished:
        """`admit` for requests whose jobs `engine.prepare` already made (on another thread: the batcher prepares
        while the cohorts step); those that failed in it are returned at once."""
        failed: Finished = [(request, error) for request, error in zip(requests, prepared.failures)
                            if error is not None]
        if prepared.jobs:
            jobs: list[SamplingJob] = prepared.jobs
            mid_run = any(running.cohort.position > 0 for running in self.running)
            self.joins_mid_run += len(jobs) if mid_run else 0
            owners = [requests[i] for i in prepared.owners]
            if self.running and self.running[-1].cohort.position == 0:   # not stepped yet: start together
                newest = self.running.pop()
                self.merged += len(jobs)
                jobs, owners = list(newest.cohort.jobs) + jobs, newest.requests + owners
                prepared.notes = newest.notes + prepared.notes
            self.running.append(_Running(self.codes.cohort(jobs, self.engine.limits.max_tokens), owners,
                                         prepared.notes))
        return failed

    def advance(self, on_step: Callable[[int], None] | None = None) -> Finished:
        """One step of each cohort the order chooses; the requests that finished in it, decoded."""
        return [(done.request, self.engine.finish(done.request, done.codes, done.notes))
                for done in self.advance_codes(on_step)]

    def advance_codes(self, on_step: Callable[[int], None] | None = None,
                      interrupt: Callable[[int], bool] | None = None) -> list[Sampled]:
        """One step of each cohort the order chooses, smallest first; the requests whose codes are done, not yet
        decoded (the caller decodes them, e.g. on another thread). `interrupt(size)` is asked, before the boundary's
        work, for each chosen cohort after the first (smallest first): true leaves that cohort and the larger ones
        out of this boundary (something much smaller is waiting to join), counted as passed over, except those
        the order says must step now."""
        done: list[Sampled] = []
        sizes = [running.cohort.shortest_job_steps() for running in self.running]
        chosen = self.order.choose(sizes, [running.skipped for running in self.running])
        stepping = sorted((size, k) for k, (size, steps) in enumerate(zip(sizes, chosen)) if steps)
        stepped: dict[int, None] = {}     # in stepping order
        for size, k in stepping:
            if stepped and interrupt is not None and not self.order.must_step(self.running[k].skipped) \
                    and interrupt(size):
                break
            stepped[k] = None
        if stepped:
            cohorts = [self.running[k].cohort for k in stepped]
            type(cohorts[0]).advance_together(cohorts, on_step)
        for k in stepped:
            running = self.running[k]
            for index, codes in running.cohort.finished():
                done.append(Sampled(running.requests[index], codes, running.notes[index]))
        for k, running in enumerate(self.running):
            running.skipped = 0 if k in stepped else running.skipped + 1
        self.running = [running for running in self.running if not running.cohort.done]
        self.steps += 1
        return done
