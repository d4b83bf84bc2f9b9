"""POST /generate with "stream": true: newline-delimited JSON whose frames, put together, are the json answer's frames
(to one unit of its 5 decimals) and whose end message is the rest of that answer; the three families; under
micro-batching; errors before the first frame as ordinary answers, after it as an error message; a client leaving
mid-stream; the time-to-first-frame metric."""
from __future__ import annotations

import json
import threading
import time

import httpx
import numpy as np
import pytest

from t2m.service.settings import Settings
from tests.service.conftest import LiveServer, wait_ready
from tests.service.fakes import FAKE_LIMITS, StreamingFakeEngine

WALK = {"segments": [{"text": "a person walks forward", "duration": 10.0}], "seed": 4}
TWO_FREE = {"segments": [{"text": "a person walks", "duration": None}, {"text": "a person waves", "duration": None}],
            "seed": 12, "guidance": 2.0}
ROUNDING = 1e-5 + 1e-9   # the frames are rounded to 5 decimals; a streamed one may land on the neighbouring value


def messages(response) -> list[dict]:
    assert response.status_code == 200, response.text
    assert response.headers["content-type"] == "application/x-ndjson"
    return [json.loads(line) for line in response.text.splitlines()]


def check_stream_equals_answer(lines: list[dict], whole: dict, tolerance: float = ROUNDING) -> list[int]:
    """The stream against the json answer of the same request: start, contiguous frames (to `tolerance`), end; the
    chunk sizes."""
    start, chunks, end = lines[0], lines[1:-1], lines[-1]
    assert start == {"type": "start", "fps": whole["fps"], "joints": whole["joints"], "parents": whole["parents"],
                     "model": whole["model"], "seed": whole["seed"]}
    assert [chunk["type"] for chunk in chunks] == ["frames"] * len(chunks)
    assert [chunk["start_frame"] for chunk in chunks] == list(np.cumsum([0] + [len(c["frames"]) for c in chunks])[:-1])
    frames = np.concatenate([np.asarray(chunk["frames"]) for chunk in chunks])
    expected = np.asarray(whole["frames"])
    assert frames.shape == expected.shape
    assert np.abs(frames - expected).max() <= tolerance
    assert end == {"type": "end", **{k: v for k, v in whole.items() if k != "frames"}, "frame_count": len(expected)}
    return [len(chunk["frames"]) for chunk in chunks]


@pytest.mark.parametrize("body", [WALK, TWO_FREE], ids=["10s", "two-free"])
def test_a_gpt_stream_equals_the_json_answer(app_client, body):
    chunks = check_stream_equals_answer(messages(app_client.post("/generate", json={**body, "stream": True})),
                                        app_client.post("/generate", json=body).json())
    assert len(chunks) > 2 and chunks[0] == 4   # early frames, the first code's at once


def test_the_gpt_model_streams_its_json_answer(make_client, gpt_model):
    client = make_client(Settings(bundle_path=gpt_model, intra_op_threads=1, verify_hashes=False))
    response = client.post("/generate", json={**WALK, "stream": True})
    assert response.headers["x-seed"] == "4" and response.headers["x-accel-buffering"] == "no"
    chunks = check_stream_equals_answer(messages(response), client.post("/generate", json=WALK).json())
    # 50 codes, the decoder sees 22 ahead: 18 codes' frames go early (at 1, 9, 18), the rest come whole
    assert chunks == [4, 32, 36, 40, 40, 40, 8]


def test_a_masked_stream_sends_the_whole_motion_in_chunks(make_client, masked_bundle):
    client = make_client(Settings(bundle_path=masked_bundle, intra_op_threads=1))
    body = {"segments": [{"text": "a person walks forward", "duration": 3.0},
                         {"text": "a person bows", "duration": None}], "seed": 2}
    whole = client.post("/generate", json=body).json()
    chunks = check_stream_equals_answer(messages(client.post("/generate", json={**body, "stream": True})), whole)
    assert all(size == 40 for size in chunks[:-1])
    # the same frames exactly: one decode either way
    assert np.array_equal(np.concatenate([np.asarray(line["frames"]) for line in messages(client.post(
        "/generate", json={**body, "stream": True}))[1:-1]]), np.asarray(whole["frames"]))


def test_a_stream_shares_a_batch_and_keeps_its_frames(make_client, random_bundle):
    client = make_client(Settings(bundle_path=random_bundle, intra_op_threads=1, batch_window_ms=400))
    streamed = {**WALK, "stream": True}
    alone = client.post("/generate", json=streamed).text
    answers: dict[str, str] = {}
    threads = [threading.Thread(target=lambda key=key, body=body: answers.__setitem__(
                   key, client.post("/generate", json=body).text))
               for key, body in (("stream", streamed), ("other", TWO_FREE), ("another", {**WALK, "seed": 9}))]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(30)
    assert client.app.state.service.models.default.batcher.largest_batch >= 2
    assert answers["stream"] == alone


@pytest.mark.parametrize("fmt", ["bvh", "glb"])
def test_only_json_streams(app_client, fmt):
    response = app_client.post("/generate", json={**WALK, "format": fmt, "stream": True})
    assert response.status_code == 422
    (error,) = response.json()["detail"]
    assert error["loc"] == ["body", "stream"] and "only the json format streams" in error["msg"]


def test_errors_before_the_first_frame_are_ordinary_answers(app_client):
    for body, loc in (({**WALK, "model": "nope"}, ["body", "model"]),
                      ({**WALK, "segments": [{"text": "x", "duration": 11}]}, ["body", "segments", 0, "duration"]),
                      ({**WALK, "top_k": 10_000}, ["body", "top_k"])):
        response = app_client.post("/generate", json={**body, "stream": True})
        assert response.status_code == 422 and response.headers["content-type"] == "application/json"
        assert [error["loc"] for error in response.json()["detail"]] == [loc]


def test_an_unknown_sentence_under_reject_is_a_422_not_a_stream(make_client, default_model):
    client = make_client(Settings(bundle_path=default_model, intra_op_threads=1, verify_hashes=False,
                                  unknown_text="reject"))
    body = {"segments": [{"text": "a person walks forward", "duration": 2.0},
                         {"text": "a person juggles three burning torches", "duration": 2.0}], "stream": True}
    response = client.post("/generate", json=body)
    assert response.status_code == 422, response.text
    assert [error["loc"] for error in response.json()["detail"]] == [["body", "segments", 1, "text"]]


def test_a_failure_after_the_first_frames_ends_the_stream_with_an_error(make_client):
    engine = StreamingFakeEngine(early=8, delay_s=5.0)
    client = make_client(Settings(request_timeout_s=0.3), engine_factory=lambda s: engine)
    lines = messages(client.post("/generate", json={**WALK, "stream": True}))
    assert [line["type"] for line in lines] == ["start", "frames", "error"]
    assert len(lines[1]["frames"]) == 8
    assert lines[2]["status"] == 504 and "0.3 s" in lines[2]["detail"]
    deadline = time.perf_counter() + 5
    while not engine.cancelled and time.perf_counter() < deadline:
        time.sleep(0.01)
    assert engine.cancelled == [True]   # the timed-out request was cancelled, not left running


def test_a_client_leaving_mid_stream_cancels_its_generation():
    from t2m.service.app import create_app

    engine = StreamingFakeEngine(early=8, delay_s=20.0)
    app = create_app(Settings(), engine_factory=lambda s: engine)
    with LiveServer(app) as server, httpx.Client(base_url=server.url, timeout=10) as http:
        with http.stream("POST", "/generate", json={**WALK, "stream": True}) as response:
            lines = response.iter_lines()
            assert json.loads(next(lines))["type"] == "start"
            assert json.loads(next(lines))["type"] == "frames"
        # the connection is closed here, mid-stream
        deadline = time.perf_counter() + 5
        while not engine.cancelled and time.perf_counter() < deadline:
            time.sleep(0.01)
        assert engine.cancelled == [True]
        engine.stream_delay_s = 0.0
        assert http.get("/health").status_code == 200
        assert http.post("/generate", json=WALK).status_code == 200
        assert app.state.service.models.default.batcher.in_flight == 0


def test_time_to_first_frame_is_a_histogram_per_model(make_client):
    client = make_client(Settings(), engine_factory=lambda s: StreamingFakeEngine(early=8))
    wait_ready(client)
    count = f't2m_time_to_first_frame_seconds_count{{model="{FAKE_LIMITS.name}"}}'
    assert f"{count} 0.0" in client.get("/metrics").text
    for _ in range(2):
        messages(client.post("/generate", json={**WALK, "stream": True}))
    client.post("/generate", json=WALK)   # not streamed: not counted
    assert f"{count} 2.0" in client.get("/metrics").text


def test_a_hifigpt_stream_equals_the_json_answer(make_client, hifigpt_bundle):
    client = make_client(Settings(bundle_path=hifigpt_bundle, intra_op_threads=1))
    body = {"segments": [{"text": "a person walks", "duration": 8.0}, {"text": "a person waves", "duration": None}],
            "seed": 8}
    chunks = check_stream_equals_answer(messages(client.post("/generate", json={**body, "stream": True})),
                                        client.post("/generate", json=body).json())
    assert len(chunks) > 2 and chunks[0] == 8   # early frames, the first step's at once
