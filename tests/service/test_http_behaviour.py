"""HTTP behaviour around generation, with stand-in engines: auth, limits, overload, timeouts, loading, errors."""
from __future__ import annotations

import threading
import time

from t2m.service.settings import Settings
from tests.service.fakes import FakeEngine

BODY = {"segments": [{"text": "a person walks", "duration": 1.0}], "seed": 1}


def test_api_key_required_when_configured(make_client):
    client = make_client(Settings(api_key="s3cret"), engine_factory=lambda s: FakeEngine())
    assert client.post("/generate", json=BODY).status_code == 401
    wrong = client.post("/generate", json=BODY, headers={"Authorization": "Bearer nope"})
    assert wrong.status_code == 401 and wrong.headers["WWW-Authenticate"] == "Bearer"
    assert "API key" in wrong.json()["detail"]
    assert client.post("/generate", json=BODY, headers={"Authorization": "Basic s3cret"}).status_code == 401
    assert client.post("/generate", json=BODY, headers={"Authorization": "Bearer s3cret"}).status_code == 200
    assert client.get("/health").status_code == 200            # health and metrics stay open for probes
    assert client.get("/metrics").status_code == 200


def test_no_key_configured_means_open(make_client):
    client = make_client(Settings(api_key=""), engine_factory=lambda s: FakeEngine())
    assert client.post("/generate", json=BODY).status_code == 200


def test_body_over_the_limit_is_413(make_client):
    client = make_client(Settings(max_body_bytes=2048), engine_factory=lambda s: FakeEngine())
    big = {"segments": [{"text": "x" * 300, "duration": 1.0}] * 10}
    response = client.post("/generate", json=big)
    assert response.status_code == 413
    assert "T2M_MAX_BODY_BYTES" in response.json()["detail"]

    def chunks():                                                # no Content-Length: counted while streaming
        for _ in range(10):
            yield b" " * 500
    streamed = client.post("/generate", content=chunks(), headers={"content-type": "application/json"})
    assert streamed.status_code == 413
    assert client.post("/generate", json=BODY).status_code == 200


def test_overload_answers_429_with_retry_after(make_client):
    gate = threading.Event()
    engine = FakeEngine(gate=gate)
    client = make_client(Settings(max_queue=1, retry_after_s=3, batch_window_ms=0), engine_factory=lambda s: engine)
    results: list[int] = []

    def post() -> None:
        results.append(client.post("/generate", json=BODY).status_code)

    first = threading.Thread(target=post)
    first.start()                                                # taken by the worker, blocked on the gate
    while not engine.batches:
        time.sleep(0.005)
    second = threading.Thread(target=post)
    second.start()                                               # waits in the queue (1 allowed)
    state = client.app.state.service
    while state.batcher.queue_depth < 1:
        time.sleep(0.005)
    metrics = client.get("/metrics").text
    assert 't2m_queue_depth{model="fake"} 1.0' in metrics and 't2m_in_flight{model="fake"} 1.0' in metrics
    refused = client.post("/generate", json=BODY)
    assert refused.status_code == 429
    assert refused.headers["Retry-After"] == "3"
    assert "busy" in refused.json()["detail"]
    refused_stream = client.post("/generate", json={**BODY, "stream": True})   # refused before any stream begins
    assert refused_stream.status_code == 429 and refused_stream.headers["content-type"] == "application/json"
    gate.set()
    first.join(10)
    second.join(10)
    assert results == [200, 200]


def test_timeout_answers_504(make_client):
    client = make_client(Settings(request_timeout_s=0.2), engine_factory=lambda s: FakeEngine(delay_s=5.0))
    started = time.perf_counter()
    response = client.post("/generate", json=BODY)
    assert response.status_code == 504
    assert "0.2 s" in response.json()["detail"]
    assert time.perf_counter() - started < 3
    # a stream whose first frames would come only with the whole motion times out the same way, as an answer
    streamed = client.post("/generate", json={**BODY, "stream": True})
    assert streamed.status_code == 504 and "0.2 s" in streamed.json()["detail"]


def test_health_is_503_while_loading_then_200(make_client):
    release = threading.Event()

    def slow_factory(settings):
        release.wait(10)
        return FakeEngine()

    client = make_client(Settings(), engine_factory=slow_factory, ready=False)
    loading = client.get("/health")
    assert loading.status_code == 503 and loading.json()["status"] == "loading"
    assert "Retry-After" in loading.headers
    busy = client.post("/generate", json=BODY)
    assert busy.status_code == 503 and "loading" in busy.json()["detail"]
    release.set()
    deadline = time.perf_counter() + 5
    while client.get("/health").status_code != 200 and time.perf_counter() < deadline:
        time.sleep(0.01)
    ready = client.get("/health").json()
    assert ready["status"] == "ok" and ready["model"]["name"] == "fake"
    assert client.post("/generate", json=BODY).status_code == 200


def test_failed_load_is_reported_by_health(make_client, tmp_path):
    client = make_client(Settings(bundle_path=tmp_path / "nowhere"), ready=False)   # the real loader
    deadline = time.perf_counter() + 5
    while client.get("/health").json()["status"] == "loading" and time.perf_counter() < deadline:
        time.sleep(0.01)
    health = client.get("/health")
    assert health.status_code == 503
    assert health.json()["status"] == "error" and "nowhere" in health.json()["detail"]
    assert client.post("/generate", json=BODY).status_code == 503


class _BrokenEngine(FakeEngine):
    def generate_batch(self, requests):
        raise RuntimeError("secret internal detail")


def test_internal_error_is_json_500_without_traceback(make_client):
    client = make_client(Settings(), engine_factory=lambda s: _BrokenEngine(), raise_server_exceptions=False)
    response = client.post("/generate", json=BODY)
    assert response.status_code == 500
    assert response.headers["content-type"].startswith("application/json")
    assert response.json() == {"detail": "internal server error"}
    assert "Traceback" not in response.text and "secret internal detail" not in response.text


def test_cors_origins_are_configurable(make_client):
    client = make_client(Settings(cors_origins="https://app.example"), engine_factory=lambda s: FakeEngine())
    allowed = client.options("/generate", headers={"Origin": "https://app.example",
                                                   "Access-Control-Request-Method": "POST"})
    assert allowed.status_code == 200
    assert allowed.headers["access-control-allow-origin"] == "https://app.example"
    response = client.post("/generate", json=BODY, headers={"Origin": "https://app.example"})
    assert "X-Seed" in response.headers["access-control-expose-headers"]
    other = client.options("/generate", headers={"Origin": "https://evil.example",
                                                 "Access-Control-Request-Method": "POST"})
    assert "access-control-allow-origin" not in other.headers


def test_no_cors_headers_by_default(make_client):
    client = make_client(Settings(), engine_factory=lambda s: FakeEngine())
    response = client.post("/generate", json=BODY, headers={"Origin": "https://app.example"})
    assert "access-control-allow-origin" not in response.headers


def test_concurrent_requests_are_batched(make_client):
    engine = FakeEngine(delay_s=0.05)
    client = make_client(Settings(batch_window_ms=100, max_batch_rows=64), engine_factory=lambda s: engine)
    codes: list[int] = []
    threads = [threading.Thread(target=lambda i=i: codes.append(
        client.post("/generate", json={**BODY, "seed": i, "guidance": 1}).status_code)) for i in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(10)
    assert codes == [200] * 4
    assert max(engine.batches) >= 2, engine.batches                # several requests shared a batch


def test_metrics_count_routes_and_statuses(make_client):
    client = make_client(Settings(), engine_factory=lambda s: FakeEngine())
    client.post("/generate", json=BODY)
    client.post("/generate", json={"segments": []})
    client.get("/no/such/path")
    text = client.get("/metrics").text
    assert 't2m_requests_total{method="POST",route="/generate",status="200"} 1.0' in text
    assert 't2m_requests_total{method="POST",route="/generate",status="422"} 1.0' in text
    assert 'route="unmatched",status="404"' in text
    assert 't2m_request_duration_seconds_bucket{le="0.1",route="/generate"}' in text
    assert 't2m_tokens_generated_total{model="fake"} 5.0' in text    # 1 s = 5 tokens
    assert 't2m_segments_generated_total{model="fake"} 1.0' in text
    assert 't2m_model_info{name="fake",version="0.0.1"} 1.0' in text
    assert 't2m_queue_depth{model="fake"} 0.0' in text and 't2m_in_flight{model="fake"} 0.0' in text


class _FailingEngine(FakeEngine):
    """Returns a given exception in place of every motion (as OnnxEngine does for a failed request)."""

    def __init__(self, error: BaseException) -> None:
        super().__init__()
        self.error = error

    def generate_batch(self, requests):
        return [self.error for _ in requests]


def test_engine_limit_error_is_422_naming_the_field(make_client):
    from t2m.runtime.types import RequestLimitError

    error = RequestLimitError("segments.0.duration", "needs 60 tokens, the model makes at most 50")
    client = make_client(Settings(), engine_factory=lambda s: _FailingEngine(error))
    response = client.post("/generate", json=BODY)
    assert response.status_code == 422
    assert response.json()["detail"][0]["loc"] == ["body", "segments", 0, "duration"]


def test_model_failure_is_500_not_422(make_client):
    client = make_client(Settings(), engine_factory=lambda s: _FailingEngine(ValueError("features contain NaN")),
                         raise_server_exceptions=False)
    response = client.post("/generate", json=BODY)
    assert response.status_code == 500 and response.json() == {"detail": "internal server error"}


def test_a_request_in_its_batch_window_counts_as_in_flight():
    """A request a worker has taken but not yet started (its batch window is open) is in no queue: the in-flight
    gauge must hold it, or a busy replica reads idle on /metrics (found by the deploy suite's drain test)."""
    from t2m.runtime.scheduling import MicroBatcher
    from t2m.runtime.types import GenerationRequest, SegmentRequest

    engine = FakeEngine()
    batcher = MicroBatcher(engine, window_s=1.0)
    try:
        future = batcher.submit_nowait(GenerationRequest([SegmentRequest("a person walks", 1.0)], seed=1))
        deadline = time.perf_counter() + 5
        while batcher.queue_depth and time.perf_counter() < deadline:
            time.sleep(0.01)
        assert batcher.queue_depth == 0 and not engine.batches        # taken, window still open, not generating
        assert batcher.in_flight == 1
        future.result(timeout=10)
        while batcher.in_flight and time.perf_counter() < deadline + 10:   # released just after the answer
            time.sleep(0.01)
        assert batcher.in_flight == 0 and engine.batches == [1]
    finally:
        batcher.close()
