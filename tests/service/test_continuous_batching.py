"""Continuous batching on the tiny random GPT and T2M-HiFiGPT bundles: a request that joins a running batch mid-run,
or leaves it early, gets exactly the motion it gets alone (same seed, same codes, same frames); joins and early
leaves are checked to have happened, by step counts, never by timing."""
from __future__ import annotations

import threading
from concurrent.futures import Future

import numpy as np
import pytest

from t2m.runtime.scheduling import ContinuousBatcher, MicroBatcher, batcher_for
from t2m.runtime.step_order import EveryCohort, ShortestFirst, step_order
from t2m.runtime.types import GenerationCancelled, GenerationRequest, Motion, SegmentRequest
from tests.service.fakes import FakeEngine


@pytest.fixture(scope="module", params=["gpt", "hifigpt"])
def engine(request, onnx_engine, hifigpt_bundle):
    """Each autoregressive family's engine (the GPT: 4 frames per step; T2M-HiFiGPT: 8, three code depths)."""
    from t2m.runtime.engine import OnnxEngine

    return onnx_engine if request.param == "gpt" else OnnxEngine.load(hifigpt_bundle, intra_op_threads=1)


def _long(seed: int = 3) -> GenerationRequest:
    """50 tokens with the guidance pair: 51 steps (T2M-HiFiGPT: 25 steps)."""
    return GenerationRequest(segments=[SegmentRequest("a person walks forward", 10.0)], seed=seed, guidance=3.0)


def _stream(seed: int = 11) -> GenerationRequest:
    """A three-sentence T2LM stream (a fixed, a free and a short segment), sampling options of its own."""
    return GenerationRequest(segments=[SegmentRequest("a person waves with the right hand", 2.0),
                                       SegmentRequest("a person bows", None),
                                       SegmentRequest("a person jumps", 0.5)],
                             seed=seed, guidance=2.0, temperature=0.8, top_k=10)


def _short(seed: int = 21) -> GenerationRequest:
    """Two fixed segments (10 + 5 tokens, stepped side by side): done 11 steps after it starts (T2M-HiFiGPT: 6)."""
    return GenerationRequest(segments=[SegmentRequest("a person turns around", 2.0),
                                       SegmentRequest("a person sits down", 1.0)], seed=seed, guidance=3.0)


def _run_until_idle(session) -> list[tuple[GenerationRequest, Motion | BaseException]]:
    finished = []
    while not session.idle:
        finished += session.advance()
    return finished


def _same_motion(got: Motion | BaseException, want: Motion) -> bool:
    return (isinstance(got, Motion) and got.segments == want.segments and got.tokens == want.tokens
            and np.array_equal(got.joints, want.joints))


def test_a_request_joining_mid_run_gets_the_motion_it_gets_alone(engine):
    long, short, stream = _long(), _short(), _stream()
    alone = {"long": engine.generate(_long()), "short": engine.generate(_short()),
             "stream": engine.generate(_stream())}
    session = engine.continuous()
    assert session.admit([long]) == []
    for _ in range(5):
        assert session.advance() == []
    assert session.admit([short, stream]) == []
    # control: they joined a batch part-way through (two cohorts, the first at step 5) ...
    assert session.joins_mid_run == 2 and [r.cohort.position for r in session.running] == [5, 0]
    finished = _run_until_idle(session)
    order = [request for request, _ in finished]
    # ... and the short one left at once, while the long one was still running
    assert order.index(short) < order.index(long)
    results = {id(request): result for request, result in finished}
    for name, request in (("long", long), ("short", short), ("stream", stream)):
        assert _same_motion(results[id(request)], alone[name]), name


def test_requests_starting_together_share_one_cohort_and_match_a_whole_batch(engine):
    batch = engine.generate_batch([_long(), _stream(), _stream(seed=12)])
    session = engine.continuous()
    requests = [_long(), _stream(), _stream(seed=12)]
    session.admit(requests)
    assert len(session.running) == 1 and session.joins_mid_run == 0
    results = {id(request): result for request, result in _run_until_idle(session)}
    for request, want in zip(requests, batch):
        assert isinstance(want, Motion) and _same_motion(results[id(request)], want)


def test_a_cancelled_request_leaves_without_changing_the_others(engine):
    alone = engine.generate(_stream())
    session = engine.continuous()
    long, stream = _long(), _stream()
    session.admit([long])
    session.advance()
    session.admit([stream])
    session.advance()
    long.cancel()
    finished = _run_until_idle(session)
    results = {id(request): result for request, result in finished}
    assert isinstance(results[id(long)], GenerationCancelled)
    assert _same_motion(results[id(stream)], alone)


def test_a_failing_request_is_answered_at_admission(engine):
    session = engine.continuous()
    bad = GenerationRequest(segments=[SegmentRequest("a person walks", 10.0)], seed=1, top_k=10_000)
    ((request, error),) = session.admit([bad])
    assert request is bad and "top_k" in str(error) and session.idle


def test_the_batcher_lets_a_request_join_a_running_batch(engine):
    """Through the service's worker thread: the second request is submitted from the worker itself after step 5 of
    the first, so it can only join mid-run; it must finish first and match its motion alone."""
    alone_long, alone_short = engine.generate(_long()), engine.generate(_short())
    order: list[str] = []
    futures: dict[str, Future] = {}
    submitted = threading.Event()
    recording = _ThreadRecordingEngine(engine)

    def on_step(steps: int) -> None:
        if steps == 5 and not submitted.is_set():
            submitted.set()
            futures["short"] = batcher.submit_nowait(_short())
            futures["short"].add_done_callback(lambda _: order.append("short"))
        elif submitted.is_set():   # the long request must not end before the helper prepared the short one
            recording.prepared.wait(timeout=60)

    batcher = ContinuousBatcher(recording, window_s=0.0, on_step=on_step)
    try:
        futures["long"] = batcher.submit_nowait(_long())
        futures["long"].add_done_callback(lambda _: order.append("long"))
        long = futures["long"].result(timeout=600)
        short = futures["short"].result(timeout=600)
    finally:
        batcher.close()
    assert order == ["short", "long"] and batcher.joins_mid_run == 1 and batcher.in_flight == 0
    assert _same_motion(short, alone_short) and _same_motion(long, alone_long)


def test_continuous_batching_is_a_setting_and_only_for_engines_that_can(onnx_engine):
    options = {"max_queue": 4, "max_batch_rows": 64, "window_s": 0.0, "workers": 1}
    made = [batcher_for(onnx_engine, continuous=True, **options), batcher_for(onnx_engine, continuous=False, **options),
            batcher_for(FakeEngine(), continuous=True, **options)]
    try:
        assert [type(b) for b in made] == [ContinuousBatcher, MicroBatcher, MicroBatcher]
    finally:
        for batcher in made:
            batcher.close()
    with pytest.raises(TypeError):
        ContinuousBatcher(FakeEngine())


def test_the_masked_family_keeps_run_to_completion_batches(masked_bundle):
    """Not autoregressive (a few whole-map passes): nothing to join between steps, so no continuous session."""
    from t2m.runtime.engine import OnnxEngine

    masked = OnnxEngine.load(masked_bundle, intra_op_threads=1)
    assert masked.continuous() is None
    batcher = batcher_for(masked, continuous=True, max_queue=4, max_batch_rows=64, window_s=0.0, workers=1)
    try:
        assert type(batcher) is MicroBatcher
    finally:
        batcher.close()


def test_shortest_first_steps_the_nearest_cohort_and_bounds_the_wait():
    order = ShortestFirst(ratio=2.0, max_skips=1)
    assert order.choose([25, 5], [0, 0]) == [False, True]          # the long one waits for the short one
    assert order.choose([25, 4], [1, 0]) == [True, True]           # ... at most max_skips boundaries in a row
    assert order.choose([10, 6, 25], [0, 0, 0]) == [True, True, False]   # within twice the nearest: they step too
    assert order.choose([], []) == []
    assert EveryCohort().choose([25, 5], [0, 0]) == [True, True]
    assert ShortestFirst(max_skips=0).choose([25, 5], [0, 0]) == [True, True]   # 0: nobody is ever passed over
    with pytest.raises(ValueError, match="ratio"):
        ShortestFirst(ratio=0.5)
    with pytest.raises(ValueError, match="unknown step order"):
        step_order("longest-first")


def _positions_while_short_runs(engine, order) -> tuple[list[int], dict[int, Motion | BaseException], list]:
    """A long request steps 3 times, a short one joins: the long cohort's position at each boundary until the short
    one is answered, and every answer."""
    session = engine.continuous(order)
    long, short = _long(), _short()
    session.admit([long])
    for _ in range(3):
        session.advance()
    session.admit([short])
    positions, finished = [], []
    while not any(request is short for request, _ in finished):
        finished += session.advance()
        positions.append(session.running[0].cohort.position)
    finished += _run_until_idle(session)
    return positions, {id(request): result for request, result in finished}, [long, short]


def test_a_short_request_runs_first_and_no_order_changes_a_motion(engine):
    alone_long, alone_short = engine.generate(_long()), engine.generate(_short())
    every, every_results, (long_e, short_e) = _positions_while_short_runs(engine, EveryCohort())
    first, first_results, (long_f, short_f) = _positions_while_short_runs(engine, ShortestFirst(max_skips=1))
    steps_of_short = len(every)
    # the short one needs as many boundaries in both orders (it steps at every one); the long one stepped at each
    # of them in the old order, and at every other one (max_skips 1) while the short one ran shortest-first
    assert len(first) == steps_of_short and every == list(range(4, 4 + steps_of_short))
    assert first[-1] - 3 == steps_of_short // 2 and all(b - a <= 1 for a, b in zip([3] + first, first))
    for results, long, short in ((every_results, long_e, short_e), (first_results, long_f, short_f)):
        assert _same_motion(results[id(long)], alone_long) and _same_motion(results[id(short)], alone_short)


def test_requests_admitted_before_the_newest_cohort_stepped_join_it(engine):
    wanted = engine.generate_batch([_long(), _short()])
    session = engine.continuous(ShortestFirst())
    long, short = _long(), _short()
    session.admit([long])
    session.admit([short])          # nothing stepped in between: the same cohort
    assert len(session.running) == 1 and session.merged == 1 and session.joins_mid_run == 0
    results = {id(request): result for request, result in _run_until_idle(session)}
    assert _same_motion(results[id(long)], wanted[0]) and _same_motion(results[id(short)], wanted[1])


def test_a_boundary_ends_early_for_a_waiting_short_request_but_never_holds_a_cohort_too_long(engine):
    """advance_codes(interrupt=...): after the first cohort's step, a cohort that may still wait is left for the
    next boundary when `interrupt` says something much smaller waits; one passed over max_skips times steps anyway.
    Codes are unchanged by it (the answers are the motions alone)."""
    alone = engine.generate(_long(3))
    session = engine.continuous(ShortestFirst(max_skips=2))
    first, second = _long(3), _long(4)
    session.admit([first])
    session.advance()
    session.admit([second])                      # two cohorts of the same size: both are chosen every time
    asked: list[int] = []
    positions = []
    for _ in range(4):
        session.advance_codes(interrupt=lambda size: asked.append(size) or True)
        positions.append([running.cohort.position for running in session.running])
    # the older cohort (sorted first among equals) steps every time; the younger one waits twice, then must step
    assert positions == [[2, 0], [3, 0], [4, 1], [5, 1]]
    assert asked and all(size == asked[0] for size in asked)
    finished = {}
    while not session.idle:
        finished.update({id(done.request): done for done in session.advance_codes()})
    motion = engine.finish(first, finished[id(first)].codes, finished[id(first)].notes)
    assert _same_motion(motion, alone)


def test_hifigpt_cohorts_of_different_ages_share_the_residual_calls(hifigpt_bundle):
    """T2M-HiFiGPT: at a boundary every stepping cohort makes its own temporal call (its own position), then the
    residual GPT's R calls run once for all their rows; the motions are still the ones alone."""
    from t2m.runtime.engine import OnnxEngine

    engine = OnnxEngine.load(hifigpt_bundle, intra_op_threads=1)
    alone = {"long": engine.generate(_long()), "short": engine.generate(_short())}
    session = engine.continuous(EveryCohort())
    long, short = _long(), _short()
    session.admit([long])
    session.advance()
    session.admit([short])
    calls: list[int] = []
    session.advance_codes(on_step=calls.append)
    rows = [running.cohort.rows for running in session.running]     # nothing finished at this boundary
    assert len(rows) == 2 and sorted(calls[:2]) == sorted(rows)     # two temporal calls, one per cohort
    assert calls[2:] == [sum(rows)] * engine.codes.temporal.depth     # then R residual calls for all rows
    finished = {id(request): result for request, result in _run_until_idle(session)}
    assert _same_motion(finished[id(long)], alone["long"]) and _same_motion(finished[id(short)], alone["short"])


class _ThreadRecordingEngine:
    """The engine, with the thread each `prepare` and `finish` the batcher calls runs on recorded. The batcher calls
    `prepare` only for requests that join while others step (on its helper; a session starting alone prepares with
    the engine itself): `prepared` is set once such a preparation returned or raised (`prepare_error`)."""

    def __init__(self, engine, prepare_error: Exception | None = None) -> None:
        self._engine, self.prepare_error = engine, prepare_error
        self.threads: list[tuple[str, str]] = []      # (call, thread name)
        self.prepared = threading.Event()

    def __getattr__(self, name: str):
        return getattr(self._engine, name)

    def prepare(self, requests):
        self.threads.append(("prepare", threading.current_thread().name))
        try:
            if self.prepare_error is not None:
                raise self.prepare_error
            return self._engine.prepare(requests)
        finally:
            self.prepared.set()

    def finish(self, request, codes, notes):
        self.threads.append(("finish", threading.current_thread().name))
        return self._engine.finish(request, codes, notes)


def _short_joining_at_step_3(engine_like) -> tuple[dict[str, Future], ContinuousBatcher]:
    """A long request through a ContinuousBatcher of `engine_like` and a short one submitted from the worker after
    the long one's step 3 (so it joins mid-run): both futures once both are done, and the closed batcher."""
    futures: dict[str, Future] = {}

    def on_step(steps: int) -> None:
        if steps == 3 and "short" not in futures:
            futures["short"] = batcher.submit_nowait(_short())
        elif "short" in futures:   # a tiny model's long request must not end before the helper prepared the short one
            engine_like.prepared.wait(timeout=60)

    batcher = ContinuousBatcher(engine_like, window_s=0.0, on_step=on_step)
    try:
        futures["long"] = batcher.submit_nowait(_long())
        futures["long"].exception(timeout=600)
        futures["short"].exception(timeout=600)
    finally:
        batcher.close()
    return futures, batcher


def test_text_encoding_and_decoding_run_beside_the_steps(engine):
    """A request that joins while a cohort steps is prepared (text graph) on the worker's helper thread, and every
    finished request is decoded there, so the steps of the running requests never wait for them; motions unchanged."""
    alone_long, alone_short = engine.generate(_long()), engine.generate(_short())
    recording = _ThreadRecordingEngine(engine)
    futures, batcher = _short_joining_at_step_3(recording)
    # the long request, alone at first, was prepared inline by the session (not through the batcher); the short one,
    # joining mid-run, on the helper; both decoded there
    assert recording.threads == [("prepare", "t2m-engine-0-helper_0")] + [("finish", "t2m-engine-0-helper_0")] * 2
    assert batcher.joins_mid_run == 1 and batcher.in_flight == 0
    assert _same_motion(futures["short"].result(), alone_short) and _same_motion(futures["long"].result(), alone_long)


def test_a_preparation_that_raises_fails_its_requests_and_nothing_else(engine):
    """The helper's text work failing (not a request's own error, which `prepare` answers itself) answers the
    requests it was preparing with that error; the cohort already stepping goes on to its motion."""
    alone_long = engine.generate(_long())
    recording = _ThreadRecordingEngine(engine, prepare_error=RuntimeError("text graph unavailable"))
    futures, batcher = _short_joining_at_step_3(recording)
    with pytest.raises(RuntimeError, match="text graph unavailable"):
        futures["short"].result()
    assert _same_motion(futures["long"].result(), alone_long) and batcher.in_flight == 0


def test_a_decoder_that_raises_still_answers_and_the_worker_goes_on(engine):
    """Decoding runs on the helper: an exception there must reach the request's answer, not vanish in a thread."""
    recording = _ThreadRecordingEngine(engine)

    def broken(request, codes, notes):
        raise MemoryError("decoder out of memory")

    recording.finish = broken
    batcher = ContinuousBatcher(recording, window_s=0.0)
    try:
        with pytest.raises(MemoryError, match="decoder out of memory"):
            batcher.submit_nowait(_short()).result(timeout=120)
        recording.finish = engine.finish
        assert _same_motion(batcher.submit_nowait(_short()).result(timeout=120), engine.generate(_short()))
    finally:
        batcher.close()
    assert batcher.in_flight == 0
