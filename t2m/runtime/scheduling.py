"""Scheduling: inference off the event loop, a bounded queue, and who joins the running work when.

A request waits in the queue (at most `max_queue`; one more is refused with QueueFullError -> 429). Worker threads
take requests out by one rule, `admit`: the queue's head always joins when nothing runs (so an oversized request
still runs, alone), and each next request in order joins while its rows fit in `max_batch_rows` beside the rows
already stepping. When a request joins is the other half: an idle worker waits `window_s` after the first request so
that requests arriving together start together; a busy one lets the head join once it has waited `window_s`.

Two ways to run what was admitted, side by side here:
- `MicroBatcher` (run to the end): the admitted requests are one batch, generated together by
  `engine.generate_batch`; the worker takes the next batch when it is done (families without cohorts, e.g. masked).
- `ContinuousBatcher` (continuous stepping): the worker keeps its engine's continuous session
  (t2m.runtime.continuous) open; the requests admitted at a step boundary start as a new cohort beside the
  running ones (or join the newest if it has not stepped yet), the cohorts its StepOrder chooses step once (the
  shortest work first: t2m.runtime.step_order), and a request is answered the step its codes are done,
  decoded on the worker's helper thread (which also prepares the requests that join while cohorts step).
Words: a *queued request* waits here; a *batch* is the requests run together to their end; a *cohort* the requests
that started stepping at one boundary; *rows* what a step's graph call computes (a segment each, two with guidance).
Each request keeps its own random generator, so no schedule changes its motion.
"""
from __future__ import annotations

import asyncio
import functools
import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Protocol, TypeVar

from t2m.runtime.continuous import PreparedJobs, Sampled
from t2m.runtime.requests import segment_steps
from t2m.runtime.step_order import ShortestFirst, StepOrder
from t2m.runtime.types import Engine, GenerationCancelled, GenerationRequest, Motion, SteppingEngine

T = TypeVar("T")

__all__ = [
    "CohortRunner",
    "ContinuousBatcher",
    "GenerationTimeout",
    "MicroBatcher",
    "QueueFullError",
    "QueuedRequest",
    "QueuedWorkers",
    "Work",
    "admit",
    "batcher_for",
    "rows_of",
    "running_cohorts",
]

log = logging.getLogger(__name__)


class QueueFullError(RuntimeError):
    """More requests are waiting than the configured bound."""


class GenerationTimeout(TimeoutError):
    """The request did not finish within its time limit."""


class Work:
    """Work for a model's engine that is not a generation (a diffusion edit: its recipe replayed and inpainted),
    queued and run by the model's batcher like a request, so that the queue's bound, its order and the queue-depth
    and in-flight metrics see it. It runs alone in its batch; cancelled (its caller timed out) before a worker takes
    it, it never runs."""

    def __init__(self, run: Callable[[], object]) -> None:
        self.run = run
        self._cancelled = threading.Event()

    def cancel(self) -> None:
        self._cancelled.set()

    @property
    def cancelled(self) -> bool:
        return self._cancelled.is_set()


def rows_of(request: GenerationRequest | Work, max_rows: int = 0) -> int:
    """Rows a request occupies per step: one per segment, two with guidance (cond + null); a Work item takes the
    whole batch (`max_rows`), so it runs alone."""
    if isinstance(request, Work):
        return max_rows
    return len(request.segments) * (1 if request.guidance == 1.0 else 2)


@dataclass
class QueuedRequest:
    """A request waiting for a worker, with the Future its answer goes to."""

    request: GenerationRequest | Work
    future: Future = field(default_factory=Future)
    enqueued: float = field(default_factory=time.perf_counter)


def generation_requests(queued: Sequence[QueuedRequest]) -> list[GenerationRequest]:
    """The generations among queued items (a Work item runs alone, and a ContinuousBatcher queues none)."""
    return [item.request for item in queued if isinstance(item.request, GenerationRequest)]


def admit(queue: deque[QueuedRequest], rows_running: int, max_rows: int) -> list[QueuedRequest]:
    """The one admission rule: take from the head of `queue` who joins now, given `rows_running` rows stepping."""
    joining: list[QueuedRequest] = []
    rows = rows_running
    while queue and (rows == 0 or rows + rows_of(queue[0].request, max_rows) <= max_rows):
        joining.append(queue.popleft())
        rows += rows_of(joining[-1].request, max_rows)
    return joining


class QueuedWorkers:
    """The bounded queue, its Futures and the worker threads; subclasses say how a worker runs what it admits."""

    def __init__(self, engine: Engine, *, max_queue: int = 16, max_batch_rows: int = 64, window_s: float = 0.005,
                 workers: int = 1) -> None:
        self.engine = engine
        self.max_queue = max_queue
        self.max_batch_rows = max_batch_rows
        self.window_s = window_s
        self._queue: deque[QueuedRequest] = deque()
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
        """Requests a worker holds: admitted (within the batch window) or being generated."""
        return self._in_flight

    def submit_nowait(self, request: GenerationRequest | Work) -> Future:
        """Queue a request (its Future resolves to a Motion) or a Work item (to what it returns). Raises
        QueueFullError if the queue is at its bound."""
        with self._cond:
            if self._closed:
                raise RuntimeError("the engine is shutting down")
            if len(self._queue) >= self.max_queue:
                raise QueueFullError(f"{len(self._queue)} requests are already waiting (limit {self.max_queue})")
            queued = QueuedRequest(request)
            self._queue.append(queued)
            self._cond.notify()
        return queued.future

    async def generate(self, request: GenerationRequest, timeout_s: float) -> Motion:
        """Generate without blocking the event loop; GenerationTimeout (and cancellation) after `timeout_s`."""
        motion: Motion = await self._answer(self.submit_nowait(request), request, timeout_s, "generation")
        return motion

    @staticmethod
    async def _answer(future: Future, item: GenerationRequest | Work, timeout_s: float, what: str) -> Any:
        """The queued item's answer, awaited off the event loop; past `timeout_s`, or when the caller goes away, the
        item is cancelled (not started if no worker took it yet, stopped at its next step if running)."""
        try:
            return await asyncio.wait_for(asyncio.wrap_future(future), timeout_s)
        except asyncio.TimeoutError:
            item.cancel()
            raise GenerationTimeout(f"{what} did not finish within {timeout_s:g} s") from None
        except asyncio.CancelledError:   # the client went away: stop spending CPU on it
            item.cancel()
            raise

    def close(self, timeout_s: float = 5.0) -> None:
        """Refuse new work, fail what is still queued, let running work finish."""
        with self._cond:
            self._closed = True
            pending = list(self._queue)
            self._queue.clear()
            self._cond.notify_all()
        for queued in pending:
            if not queued.future.done():
                queued.future.set_exception(GenerationCancelled("the service is shutting down"))
        for thread in self._threads:
            thread.join(timeout_s)

    def _next_admitted(self, rows_running: int) -> list[QueuedRequest] | None:
        """Who joins now (`admit`), and when. Idle: block for the first request, then for up to window_s admit the
        others as they arrive, while their rows fit. Busy: never block, and admit once the queue's head has waited
        window_s. None when closed and nothing runs. An admitted request counts as in flight at once: it is in no
        queue now, and a replica that holds requests must never look idle on /metrics (autoscaling, drain checks)."""
        with self._cond:
            if rows_running > 0:
                if self._closed or not self._queue or time.perf_counter() - self._queue[0].enqueued < self.window_s:
                    return []
                joining = admit(self._queue, rows_running, self.max_batch_rows)
                self._in_flight += len(joining)
                return joining
            while not self._queue and not self._closed:
                self._cond.wait()
            if self._closed:
                return None
            deadline = time.perf_counter() + self.window_s
            joining, rows = [], 0
            while True:
                taken = admit(self._queue, rows, self.max_batch_rows)
                joining += taken
                rows += sum(rows_of(queued.request, self.max_batch_rows) for queued in taken)
                self._in_flight += len(taken)
                remaining = deadline - time.perf_counter()
                if remaining <= 0 or self._queue or rows >= self.max_batch_rows or self._closed:
                    return joining
                self._cond.wait(remaining)

    def _live(self, joining: Sequence[QueuedRequest]) -> list[QueuedRequest]:
        """The admitted requests still wanted; those cancelled while queued are answered (and released) now."""
        live = []
        for queued in joining:
            if queued.request.cancelled:
                self._finish(queued, GenerationCancelled("request cancelled while queued"))
            else:
                live.append(queued)
        return live

    def _finish(self, queued: QueuedRequest, result: object) -> None:
        """Hand a request its Motion or its failure, once, and release its place."""
        if not queued.future.done():
            if isinstance(result, BaseException):
                queued.future.set_exception(result)
            else:
                queued.future.set_result(result)
        with self._cond:
            self._in_flight -= 1


class MicroBatcher(QueuedWorkers):
    """Run to the end: the admitted requests are one batch, generated together before the worker admits more."""

    async def run(self, work: Callable[[], T], timeout_s: float) -> T:
        """`work()` in the model's queue, alone in its batch, without blocking the event loop; GenerationTimeout
        after `timeout_s` (the work is then cancelled: never started if no worker took it yet)."""
        item = Work(work)
        result: T = await self._answer(self.submit_nowait(item), item, timeout_s, "the work")
        return result

    def _work(self) -> None:
        while True:
            joining = self._next_admitted(0)
            if joining is None:
                return
            live = self._live(joining)
            if not live:
                continue
            self.batches_run += 1
            self.largest_batch = max(self.largest_batch, len(live))
            work = live[0].request
            if isinstance(work, Work):   # admitted alone (it takes the whole batch)
                try:
                    result: object = work.run()
                except BaseException as error:  # the work's own errors go to its caller
                    result = error
                self._finish(live[0], result)
                continue
            try:
                results: Sequence[object] = self.engine.generate_batch(generation_requests(live))
            except BaseException as error:  # an engine failure fails its batch, never the worker
                log.exception("generation batch of %d failed", len(live))
                results = [error] * len(live)
            for queued, result in zip(live, results):
                self._finish(queued, result)


class CohortRunner(Protocol):
    """An engine's running work (t2m.runtime.continuous.RunningCohorts)."""

    steps: int
    joins_mid_run: int

    @property
    def rows(self) -> int: ...

    @property
    def idle(self) -> bool: ...

    def admit(self, requests: Sequence[GenerationRequest]) -> list[tuple[GenerationRequest, Motion | BaseException]]:
        ...

    def admit_prepared(self, requests: Sequence[GenerationRequest],
                       prepared: PreparedJobs) -> list[tuple[GenerationRequest, Motion | BaseException]]: ...

    def advance(self) -> list[tuple[GenerationRequest, Motion | BaseException]]: ...

    def advance_codes(self, on_step: Callable[[int], None] | None = None,
                      interrupt: Callable[[int], bool] | None = None) -> list[Sampled]: ...


def running_cohorts(engine: Engine, order: StepOrder | None = None) -> CohortRunner | None:
    """A new continuous session of `engine` stepping its cohorts in `order` (engine/step_order.py; None: the
    default, shortest work first), or None if it has none (its family runs batches to their end)."""
    if not isinstance(engine, SteppingEngine):
        return None
    return engine.continuous(order) if order is not None else engine.continuous()


class ContinuousBatcher(QueuedWorkers):
    """Continuous stepping: each worker keeps a running session that requests join and leave at step boundaries."""

    def __init__(self, engine: Engine, *, max_queue: int = 16, max_batch_rows: int = 64, window_s: float = 0.005,
                 workers: int = 1, on_step: Callable[[int], None] | None = None,
                 step_order: StepOrder | None = None) -> None:
        """`on_step(steps)` runs in the worker after each step boundary (tests use it to submit mid-run);
        `step_order`: which cohorts step at a boundary (engine/step_order.py; None: shortest work first)."""
        if not isinstance(engine, SteppingEngine) or running_cohorts(engine) is None:
            raise TypeError(f"{type(engine).__name__} has no continuous session; use MicroBatcher")
        self.stepping: SteppingEngine = engine
        self.on_step = on_step
        self.step_order = step_order or ShortestFirst()
        self.joins_mid_run = 0       # requests that joined while another was part-way through (all workers)
        super().__init__(engine, max_queue=max_queue, max_batch_rows=max_batch_rows, window_s=window_s,
                         workers=workers)

    def _smaller_waiting(self, size: int, preparing: Sequence[GenerationRequest] = ()) -> bool:
        """Whether a request much smaller (the order's ratio) than a cohort of `size` steps waits to join (queued,
        or admitted and being prepared): then the boundary ends before that cohort (engine/continuous.py
        RunningCohorts.advance_codes)."""
        ratio = self.step_order.ratio
        if ratio is None:
            return False
        with self._cond:
            waiting = generation_requests(self._queue)
        return any(ratio * self._request_steps(request) < size for request in [*waiting, *preparing])

    def _request_steps(self, request: GenerationRequest) -> int:
        """A queued request's size in steps: its longest segment (a null duration counts as the model's longest;
        a request its model refuses counts as the longest too: admission answers it)."""
        limits = self.engine.limits
        try:
            steps = segment_steps(request, limits)
        except Exception:
            return limits.max_tokens
        return max(limits.max_tokens if n is None else n for n in steps)

    def _session(self) -> CohortRunner:
        session = running_cohorts(self.engine, self.step_order)
        assert session is not None  # checked in __init__
        return session

    def _work(self) -> None:
        """Step the session; text encoding (`engine.prepare`) and decoding (`engine.finish`) of requests that join
        or leave while cohorts step run on a helper thread beside it, so the steps of the requests already running
        (a short one among long ones) do not wait for other requests' text graph or decoder."""
        helper = ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"{threading.current_thread().name}-helper")
        try:
            self._step_loop(helper)
        finally:
            helper.shutdown(wait=True)

    def _step_loop(self, helper: ThreadPoolExecutor) -> None:
        session = self._session()
        running: dict[int, QueuedRequest] = {}       # id(request) -> its queue entry
        preparing: tuple[list[QueuedRequest], Future] | None = None   # admitted, its jobs being made on the helper
        while True:
            # one preparation at a time: what arrives meanwhile waits in the queue and joins as one cohort after it
            # (a graph call per cohort per step: many small cohorts would cost more than the text work saves)
            joining = [] if preparing else self._next_admitted(session.rows)
            if joining is None:
                return
            try:
                live = self._live(joining)
                if live and session.idle:   # nothing steps: no reason to hand over
                    self._admit(session, live, None, running)
                elif live:
                    preparing = live, helper.submit(self.stepping.prepare, generation_requests(live))
                if preparing and (session.idle or preparing[1].done()):
                    ready, preparing = preparing, None
                    self._admit(session, *ready, running=running)
                if session.idle:
                    continue
                waiting = tuple(generation_requests(preparing[0])) if preparing else ()
                for done in session.advance_codes(interrupt=functools.partial(self._smaller_waiting,
                                                                              preparing=waiting)):
                    helper.submit(self._decode, running.pop(id(done.request)), done)
            except BaseException as error:  # an engine failure fails what it was running, never the worker
                log.exception("continuous generation of %d requests failed", len(running))
                for queued in running.values():
                    self._finish(queued, error)
                running.clear()
                session = self._session()
            if self.on_step is not None:
                self.on_step(session.steps)

    def _admit(self, session: CohortRunner, live: list[QueuedRequest], prepared: Future | None,
               running: dict[int, QueuedRequest]) -> None:
        """Start `live` as a cohort with the jobs `prepared` made (None: prepare them here); those that failed
        before sampling are answered now (all of them, if the preparation itself raised: the running ones go on)."""
        requests = generation_requests(live)
        if prepared is not None:
            try:
                jobs = prepared.result()
            except Exception as error:
                log.exception("preparing %d requests failed", len(live))
                for queued in live:
                    self._finish(queued, error)
                return
        for queued in live:
            running[id(queued.request)] = queued
        mid_run = session.joins_mid_run
        finished = session.admit(requests) if prepared is None else session.admit_prepared(requests, jobs)
        for request, result in finished:
            self._finish(running.pop(id(request)), result)
        self.joins_mid_run += session.joins_mid_run - mid_run
        self.batches_run += 1
        self.largest_batch = max(self.largest_batch, len(running))

    def _decode(self, queued: QueuedRequest, done: Sampled) -> None:
        """On the helper: a request whose codes are done, decoded and answered (with the failure, if any: nothing
        raised on the helper may leave a request unanswered)."""
        try:
            result = self.stepping.finish(done.request, done.codes, done.notes)
        except BaseException as error:
            log.exception("decoding a finished request failed")
            result = error
        self._finish(queued, result)


def batcher_for(engine: Engine, *, continuous: bool, max_queue: int, max_batch_rows: int, window_s: float,
                workers: int, step_order: StepOrder | None = None) -> QueuedWorkers:
    """ContinuousBatcher (its cohorts stepped in `step_order`) when asked for and the engine has a continuous
    session, else MicroBatcher."""
    if continuous and running_cohorts(engine) is not None:
        return ContinuousBatcher(engine, max_queue=max_queue, max_batch_rows=max_batch_rows, window_s=window_s,
                                 workers=workers, step_order=step_order)
    return MicroBatcher(engine, max_queue=max_queue, max_batch_rows=max_batch_rows, window_s=window_s,
                        workers=workers)
