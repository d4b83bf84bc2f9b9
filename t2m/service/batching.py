"""Inference off the event loop: a bounded queue, worker threads and micro-batching of concurrent requests.

A request waits in the queue (at most `max_queue` of them; one more is refused with QueueFullError -> 429). A worker
takes the oldest request, then for `window_s` lets others join while their GPT rows fit in `max_batch_rows`; the
batch's segments then step through the GPT graph together (engine.generate_batch), which costs little more than one
request on a CPU because a step's cost is dominated by reading the weights. Each request keeps its own random
generator, so batching never changes a request's motion.

`QueuedWorkers` is the queue, the bound, the Futures and the threads; `MicroBatcher` runs each batch to its end;
`t2m.service.continuous_batching.ContinuousBatcher` (the GPT family's default) lets requests join a running batch.
"""
from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections import deque
from concurrent.futures import Future
from dataclasses import dataclass, field

from t2m.service.engine.types import Engine, GenerationCancelled, GenerationRequest, Motion

__all__ = ["GenerationTimeout", "MicroBatcher", "QueueFullError", "QueuedWorkers", "rows_of"]

log = logging.getLogger(__name__)


class QueueFullError(RuntimeError):
    """More requests are waiting than the configured bound."""


class GenerationTimeout(TimeoutError):
    """The request did not finish within its time limit."""


def rows_of(request: GenerationRequest) -> int:
    """GPT rows a request occupies per step: one per segment, two with guidance (cond + null)."""
    return len(request.segments) * (1 if request.guidance == 1.0 else 2)


@dataclass
class _Job:
    request: GenerationRequest
    future: Future = field(default_factory=Future)
    enqueued: float = field(default_factory=time.perf_counter)


class QueuedWorkers:
    """A bounded queue of requests served by worker threads; subclasses say how a worker runs them (`_work`)."""

    def __init__(self, engine: Engine, *, max_queue: int = 16, max_batch_rows: int = 64, window_s: float = 0.005,
                 workers: int = 1) -> None:
        self.engine = engine
        self.max_queue = max_queue
        self.max_batch_rows = max_batch_rows
        self.window_s = window_s
        self._queue: deque[_Job] = deque()
        self._cond = threading.Condition()
        self._closed = False
        self._in_flight = 0
        self.batches_run = 0
        self.largest_batch = 0
        self._threads = [threading.Thread(target=self._work, name=f"t2m-engine-{i}", daemon=True)
                         for i in range(workers)]
        for thread in self._threads:
            thread.start()

    def _work(self) -> None:
        raise NotImplementedError

    @property
    def queue_depth(self) -> int:
        """Requests waiting for a worker."""
        return len(self._queue)

    @property
    def in_flight(self) -> int:
        """Requests a worker holds: gathered into its batch (within the batch window) or being generated."""
        return self._in_flight

    def submit_nowait(self, request: GenerationRequest) -> Future:
        """Queue a request; its Future resolves to a Motion. Raises QueueFullError if the queue is at its bound."""
        with self._cond:
            if self._closed:
                raise RuntimeError("the engine is shutting down")
            if len(self._queue) >= self.max_queue:
                raise QueueFullError(f"{len(self._queue)} requests are already waiting (limit {self.max_queue})")
            job = _Job(request)
            self._queue.append(job)
            self._cond.notify()
        return job.future

    async def generate(self, request: GenerationRequest, timeout_s: float) -> Motion:
        """Generate without blocking the event loop; GenerationTimeout (and cancellation) after `timeout_s`."""
        future = self.submit_nowait(request)
        try:
            return await asyncio.wait_for(asyncio.wrap_future(future), timeout_s)
        except asyncio.TimeoutError:
            request.cancel()
            raise GenerationTimeout(f"generation did not finish within {timeout_s:g} s") from None
        except asyncio.CancelledError:   # the client went away: stop spending CPU on it
            request.cancel()
            raise

    def close(self, timeout_s: float = 5.0) -> None:
        """Refuse new work, fail what is still queued, let running batches finish."""
        with self._cond:
            self._closed = True
            pending = list(self._queue)
            self._queue.clear()
            self._cond.notify_all()
        for job in pending:
            if not job.future.done():
                job.future.set_exception(GenerationCancelled("the service is shutting down"))
        for thread in self._threads:
            thread.join(timeout_s)

    def _resolve(self, job: _Job, result: object) -> None:
        """Hand a finished job its Motion or its failure, once."""
        if job.future.done():
            return
        if isinstance(result, BaseException):
            job.future.set_exception(result)
        else:
            job.future.set_result(result)


class MicroBatcher(QueuedWorkers):
    """Runs an engine's generations in worker threads, batching requests that arrive together; a batch runs to its
    end before the worker takes the next."""

    # ---------------------------------------------------------------------------------------- worker side

    def _take_batch(self) -> list[_Job] | None:
        """Block for the first job, then gather more for up to window_s while their rows fit."""
        with self._cond:
            while not self._queue and not self._closed:
                self._cond.wait()
            if self._closed:
                return None
            batch = [self._queue.popleft()]
            # a job gathered into a batch counts as in flight at once: during the window it is in no queue, and a
            # replica that holds requests must never look idle on /metrics (autoscaling, drain checks)
            self._in_flight += 1
            rows = rows_of(batch[0].request)
            deadline = time.perf_counter() + self.window_s
            while True:
                while self._queue and rows + rows_of(self._queue[0].request) <= self.max_batch_rows:
                    job = self._queue.popleft()
                    batch.append(job)
                    self._in_flight += 1
                    rows += rows_of(job.request)
                remaining = deadline - time.perf_counter()
                if remaining <= 0 or self._queue or rows >= self.max_batch_rows:
                    break
                self._cond.wait(remaining)
            return batch

    def _work(self) -> None:
        while True:
            batch = self._take_batch()
            if batch is None:
                return
            live = [job for job in batch if not job.request.cancelled]
            for job in batch:
                if job.request.cancelled and not job.future.done():
                    job.future.set_exception(GenerationCancelled("request cancelled while queued"))
            try:
                if live:
                    self.batches_run += 1
                    self.largest_batch = max(self.largest_batch, len(live))
                    results = self.engine.generate_batch([job.request for job in live])
                    for job, result in zip(live, results):
                        self._resolve(job, result)
            except BaseException as error:  # an engine failure fails its batch, never the worker
                log.exception("generation batch of %d failed", len(live))
                for job in live:
                    if not job.future.done():
                        job.future.set_exception(error)
            finally:
                with self._cond:
                    self._in_flight -= len(batch)
