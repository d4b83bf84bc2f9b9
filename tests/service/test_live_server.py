"""A real uvicorn on 127.0.0.1: raw HTTP edge cases and the Python SDK (sync and async, error types)."""
from __future__ import annotations

import asyncio
import json
import threading
import time

import httpx
import numpy as np
import pytest

from t2m.client import (
    AsyncT2MClient,
    AuthError,
    FrameChunk,
    Motion,
    OverloadedError,
    Segment,
    ServerError,
    T2MClient,
    T2MConnectionError,
    T2MError,
    ValidationError,
)
from tests.service.conftest import LiveServer, free_port
from tests.service.fakes import FakeEngine, StreamingFakeEngine

KEY = {"Authorization": "Bearer test-key"}
SEGMENTS = [("a person walks forward", 3.0), ("a person waves with the right hand", 2.0)]


def test_raw_http_edge_cases(live_server):
    url = live_server.url
    body = {"segments": [{"text": "walk", "duration": 1.0}], "seed": 3}
    assert httpx.post(url + "/generate", json=body).status_code == 401
    assert httpx.post(url + "/generate", json=body, headers={"Authorization": "Bearer nope"}).status_code == 401
    ok = httpx.post(url + "/generate", json=body, headers=KEY)
    assert ok.status_code == 200 and len(ok.json()["frames"]) == 20
    bad = httpx.post(url + "/generate", content=b"{oops", headers={**KEY, "content-type": "application/json"})
    assert 400 <= bad.status_code < 500 and "Traceback" not in bad.text
    big = httpx.post(url + "/generate", content=b" " * 100_000, headers={**KEY, "content-type": "application/json"})
    assert big.status_code == 413

    def chunks():
        for _ in range(100):
            yield b" " * 1000
    streamed = httpx.post(url + "/generate", content=chunks(), headers={**KEY, "content-type": "application/json"})
    assert streamed.status_code == 413
    assert httpx.get(url + "/metrics").text.count("t2m_requests_total{") >= 3


def test_sync_sdk(live_server, tmp_path):
    with T2MClient(live_server.url, api_key="test-key", timeout=30) as t2m:
        health = t2m.health()
        assert health.ready and health.model["name"] == "t2m-random-test"
        motion = t2m.generate(SEGMENTS, seed=7)
        assert isinstance(motion, Motion) and motion.frames.shape == (100, 22, 3)
        assert motion.frames.dtype == np.float32 and motion.fps == 20 and motion.seed == 7
        assert len(motion.joints) == 22 and motion.parents[0] == -1 and motion.duration == 5.0
        assert [(s.start_frame, s.end_frame) for s in motion.segments] == [(0, 60), (60, 100)]
        assert np.array_equal(t2m.generate([Segment(t, d) for t, d in SEGMENTS], seed=7).frames, motion.frames)
        free = t2m.generate("a person jumps")                   # a single sentence, free length, random seed
        assert free.num_frames % 4 == 0 and free.seed >= 0
        assert np.array_equal(t2m.generate("a person jumps", seed=free.seed).frames, free.frames)
        bvh = t2m.generate_bvh(SEGMENTS, seed=7, guidance=2.0, temperature=0.9, top_k=16)
        assert bvh.startswith("HIERARCHY")
        assert t2m.save_bvh(tmp_path / "m.bvh", SEGMENTS, seed=7, guidance=2.0, temperature=0.9,
                            top_k=16).read_text() == bvh
        glb = t2m.generate_glb(SEGMENTS, seed=7)
        assert glb[:4] == b"glTF"
        assert t2m.save_glb(tmp_path / "m.glb", SEGMENTS, seed=7).read_bytes() == glb
        raw = t2m.generate_raw(SEGMENTS, "bvh")
        assert raw.seed is not None and raw.content.startswith(b"HIERARCHY")


def test_sync_sdk_errors(live_server):
    with T2MClient(live_server.url, api_key="test-key") as t2m:
        with pytest.raises(ValidationError) as error:
            t2m.generate([("", 3.0), ("walk", 30.0)], top_k=0)
        assert set(error.value.fields) == {"segments.0.text", "segments.1.duration", "top_k"}
        assert error.value.status_code == 422 and "segments.1.duration" in str(error.value)
        with pytest.raises(ValidationError) as error:
            t2m.generate(SEGMENTS, top_k=1000)                   # a model limit (codebook 32)
        assert error.value.fields == ["top_k"]
    with T2MClient(live_server.url, api_key="wrong") as t2m, pytest.raises(AuthError) as auth:
        t2m.generate(SEGMENTS)
    assert auth.value.status_code == 401
    with T2MClient(f"http://127.0.0.1:{free_port()}") as t2m, pytest.raises(T2MConnectionError):
        t2m.health()


def test_async_sdk(live_server, tmp_path):
    async def scenario() -> None:
        async with AsyncT2MClient(live_server.url, api_key="test-key", timeout=30) as t2m:
            assert (await t2m.health()).ready
            motions = await asyncio.gather(*(t2m.generate(SEGMENTS, seed=s) for s in (1, 1, 2)))
            assert np.array_equal(motions[0].frames, motions[1].frames)
            assert not np.array_equal(motions[0].frames, motions[2].frames)
            assert (await t2m.generate_bvh(SEGMENTS, seed=1)).startswith("HIERARCHY")
            assert (await t2m.save_glb(tmp_path / "a.glb", SEGMENTS, seed=1)).read_bytes()[:4] == b"glTF"
            with pytest.raises(ValidationError) as error:
                await t2m.generate([("walk", 0.1)])
            assert error.value.fields == ["segments.0.duration"]
        async with AsyncT2MClient(live_server.url) as anonymous:
            with pytest.raises(AuthError):
                await anonymous.generate(SEGMENTS)

    asyncio.run(scenario())


def test_sdk_overload_and_timeout_errors():
    from t2m.service.app import create_app
    from t2m.service.settings import Settings

    gate = threading.Event()
    engine = FakeEngine(gate=gate)
    app = create_app(Settings(max_queue=1, batch_window_ms=0, request_timeout_s=1.0, retry_after_s=2),
                     engine_factory=lambda s: engine)
    with LiveServer(app) as server, T2MClient(server.url, timeout=10) as t2m:
        results: list[object] = []

        def call() -> None:
            try:
                results.append(t2m.generate("walk", seed=1))
            except Exception as error:  # collected and checked below
                results.append(error)

        first = threading.Thread(target=call)
        first.start()
        while not engine.batches:
            time.sleep(0.005)
        second = threading.Thread(target=call)
        second.start()
        while app.state.service.batcher.queue_depth < 1:
            time.sleep(0.005)
        with pytest.raises(OverloadedError) as overloaded:
            t2m.generate("walk")
        assert overloaded.value.retry_after == 2.0 and overloaded.value.status_code == 429
        first.join(10)
        second.join(10)
        timeouts = [r for r in results if isinstance(r, ServerError)]
        assert timeouts and all(r.status_code == 504 for r in timeouts), results
        gate.set()


def _check_streamed(items: list, whole: Motion) -> None:
    """FrameChunks in order, then the Motion: its frames are the chunks', and the unstreamed motion's to 1e-5."""
    *chunks, motion = items
    assert len(chunks) > 2 and all(isinstance(chunk, FrameChunk) for chunk in chunks) and isinstance(motion, Motion)
    assert [c.start_frame for c in chunks] == list(np.cumsum([0] + [len(c.frames) for c in chunks])[:-1])
    assert np.array_equal(np.concatenate([chunk.frames for chunk in chunks]), motion.frames)
    assert np.abs(motion.frames - whole.frames).max() <= 1e-5 + 1e-6
    assert (motion.seed, motion.segments, motion.model, motion.warnings) == (whole.seed, whole.segments,
                                                                             whole.model, whole.warnings)


def test_sync_sdk_streams_frames(live_server):
    walk = [("a person walks forward", 10.0)]
    with T2MClient(live_server.url, api_key="test-key", timeout=30) as t2m:
        _check_streamed(list(t2m.generate_stream(walk, seed=3)), t2m.generate(walk, seed=3))
        with pytest.raises(ValidationError) as error:   # refused before any frame: raised as iteration starts
            next(iter(t2m.generate_stream([("walk", 0.1)])))
        assert error.value.fields == ["segments.0.duration"]


def test_async_sdk_streams_frames(live_server):
    walk = [("a person walks forward", 10.0), ("a person waves with the right hand", None)]

    async def scenario() -> None:
        async with AsyncT2MClient(live_server.url, api_key="test-key", timeout=30) as t2m:
            items = [item async for item in t2m.generate_stream(walk, seed=5)]
            _check_streamed(items, await t2m.generate(walk, seed=5))
            with pytest.raises(ValidationError):
                await anext(t2m.generate_stream([("walk", 0.1)]))

    asyncio.run(scenario())


def test_the_sdk_refuses_a_broken_stream():
    from t2m.client._common import StreamReader

    start = json.dumps({"type": "start", "fps": 20, "joints": ["a"], "parents": [-1], "model": {}, "seed": 1})
    frames = json.dumps({"type": "frames", "start_frame": 0, "frames": [[[0.0, 1.0, 2.0]]]})
    end = json.dumps({"type": "end", "fps": 20, "joints": ["a"], "parents": [-1], "segments": [], "seed": 1,
                      "model": {"name": "m", "version": "1"}, "warnings": [], "frame_count": 2})
    reader = StreamReader()
    reader.feed(start)
    reader.feed(frames)
    with pytest.raises(T2MError, match="out of order"):
        reader.feed(frames)                      # frames from 0 again: a repeated or lost message
    with pytest.raises(T2MError, match="end message says 2"):
        reader.feed(end)                         # one frame arrived, the end counts two
    cut = StreamReader()
    cut.feed(start)
    with pytest.raises(T2MConnectionError, match="without its end message"):
        cut.finish()                             # the connection closed before the end


def test_sdk_stream_failing_after_its_first_frames_raises_server_error():
    from t2m.service.app import create_app
    from t2m.service.settings import Settings

    app = create_app(Settings(request_timeout_s=0.3), engine_factory=lambda s: StreamingFakeEngine(early=8,
                                                                                                    delay_s=5.0))
    with LiveServer(app) as server, T2MClient(server.url, timeout=10) as t2m:
        stream = t2m.generate_stream("walk", seed=1)
        first = next(stream)
        with pytest.raises(ServerError) as failure:
            next(stream)
    assert isinstance(first, FrameChunk) and len(first.frames) == 8
    assert failure.value.status_code == 504
