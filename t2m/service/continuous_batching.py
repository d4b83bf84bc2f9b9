"""Continuous batching: a request that arrives while others are generating joins them at the next step boundary.

The worker keeps one continuous session of its engine (t2m.service.engine.continuous). Between two steps it admits
the queued requests whose rows fit beside the running ones (`max_batch_rows` counts all rows stepping), then steps
everything once; a request is answered the step its codes are done, so a short request is not held until the long
ones it shares the worker with are finished. A request waits up to `window_s` before joining, so that requests
arriving together start together (one cohort, one graph call per step, t2m.decoding.lockstep.Cohort). Engines
without a continuous session (the masked family, test stand-ins) are served by MicroBatcher instead (`batcher_for`).
"""
from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from typing import Protocol

from t2m.service.batching import MicroBatcher, QueuedWorkers, _Job, rows_of
from t2m.service.engine.types import Engine, GenerationCancelled, GenerationRequest, Motion

__all__ = ["ContinuousBatcher", "ContinuousSession", "batcher_for", "continuous_session"]

log = logging.getLogger(__name__)


class ContinuousSession(Protocol):
    """An engine's running work (t2m.service.engine.continuous.ContinuousCohorts)."""

    steps: int
    joins_mid_run: int

    @property
    def rows(self) -> int: ...

    @property
    def idle(self) -> bool: ...

    def admit(self, requests: Sequence[GenerationRequest]) -> list[tuple[GenerationRequest, Motion | BaseException]]:
        ...

    def advance(self) -> list[tuple[GenerationRequest, Motion | BaseException]]: ...


def continuous_session(engine: Engine) -> ContinuousSession | None:
    """A new continuous session of `engine`, or None if it has none (its family keeps micro-batching)."""
    make = getattr(engine, "continuous", None)
    return make() if callable(make) else None


class ContinuousBatcher(QueuedWorkers):
    """Worker threads that each keep a running batch open for requests to join and leave at step boundaries."""

    def __init__(self, engine: Engine, *, max_queue: int = 16, max_batch_rows: int = 64, window_s: float = 0.005,
                 workers: int = 1, on_step: Callable[[int], None] | None = None) -> None:
        """`on_step(steps)` runs in the worker after each step boundary (tests use it to submit mid-run)."""
        if continuous_session(engine) is None:
            raise TypeError(f"{type(engine).__name__} has no continuous session; use MicroBatcher")
        self.on_step = on_step
        self.joins_mid_run = 0       # requests that joined while another was part-way through (all workers)
        super().__init__(engine, max_queue=max_queue, max_batch_rows=max_batch_rows, window_s=window_s,
                         workers=workers)

    def _take_joining(self, rows: int) -> list[_Job] | None:
        """The queued jobs that join now, given `rows` stepping already; None when closed and nothing runs.

        Idle: block for the first job, then gather others for up to window_s (as MicroBatcher does). Busy: never
        block; the queue's head joins once it has waited window_s, with whatever follows it and still fits."""
        with self._cond:
            if rows == 0:
                while not self._queue and not self._closed:
                    self._cond.wait()
                if self._closed:
                    return None
                deadline = time.perf_counter() + self.window_s
                while len(self._queue) < self.max_queue and not self._closed:
                    remaining = deadline - time.perf_counter()
                    if remaining <= 0 or sum(rows_of(job.request) for job in self._queue) >= self.max_batch_rows:
                        break
                    self._cond.wait(remaining)
            elif self._closed or not self._queue or time.perf_counter() - self._queue[0].enqueued < self.window_s:
                return []
            joining: list[_Job] = []
            while self._queue and (rows == 0 or rows + rows_of(self._queue[0].request) <= self.max_batch_rows):
                job = self._queue.popleft()
                joining.append(job)
                rows += rows_of(job.request)
            self._in_flight += len(joining)
            return joining

    def _session(self) -> ContinuousSession:
        session = continuous_session(self.engine)
        assert session is not None  # checked in __init__
        return session

    def _finish(self, job: _Job, result: object) -> None:
        self._resolve(job, result)
        with self._cond:
            self._in_flight -= 1

    def _work(self) -> None:
        session = self._session()
        running: dict[int, _Job] = {}       # id(request) -> its job
        while True:
            joining = self._take_joining(session.rows)
            if joining is None:
                return
            try:
                live = []
                for job in joining:
                    if job.request.cancelled:
                        self._finish(job, GenerationCancelled("request cancelled while queued"))
                        continue
                    running[id(job.request)] = job
                    live.append(job.request)
                if live:
                    mid_run = session.joins_mid_run
                    for request, result in session.admit(live):
                        self._finish(running.pop(id(request)), result)
                    self.joins_mid_run += session.joins_mid_run - mid_run
                    self.batches_run += 1
                    self.largest_batch = max(self.largest_batch, len(running))
                if session.idle:
                    continue
                for request, result in session.advance():
                    self._finish(running.pop(id(request)), result)
            except BaseException as error:  # an engine failure fails what it was running, never the worker
                log.exception("continuous generation of %d requests failed", len(running))
                for job in running.values():
                    self._finish(job, error)
                running.clear()
                session = self._session()
            if self.on_step is not None:
                self.on_step(session.steps)


def batcher_for(engine: Engine, *, continuous: bool, max_queue: int, max_batch_rows: int, window_s: float,
                workers: int) -> QueuedWorkers:
    """ContinuousBatcher when asked for and the engine has a continuous session, else MicroBatcher."""
    kind = ContinuousBatcher if continuous and continuous_session(engine) is not None else MicroBatcher
    return kind(engine, max_queue=max_queue, max_batch_rows=max_batch_rows, window_s=window_s, workers=workers)
