"""Half-sent requests are answered 408 and closed within their deadline, on a real uvicorn with the
service's protocol (service/request_deadlines.py); plain uvicorn keeps them open. Short deadlines keep this fast; the
same against a `t2m serve` process with many connections is in tests/fuzz/test_hostile_inputs.py (slow suite)."""
from __future__ import annotations

import json
import threading
from concurrent.futures import ThreadPoolExecutor

import httpx
import pytest

from t2m.service.request_deadlines import deadline_protocol
from t2m.service.settings import Settings
from tests.raw_http import exchange, split
from tests.service.conftest import LiveServer
from tests.service.fakes import FakeEngine

HEADER_S, BODY_S = 0.5, 0.8
SLACK_S = 0.5   # a busy 2-core machine: the close may come this much after the deadline
GENERATE = json.dumps({"segments": [{"text": "a person walks", "duration": 1.0}], "seed": 1}).encode()
HEAD = b"POST /generate HTTP/1.1\r\nHost: t\r\nContent-Type: application/json\r\nContent-Length: %d\r\n\r\n"
REQUEST = HEAD % len(GENERATE) + GENERATE


@pytest.fixture(scope="module")
def gate() -> threading.Event:
    return threading.Event()


@pytest.fixture(scope="module")
def server(gate):
    from t2m.service.app import create_app

    engine = FakeEngine()
    app = create_app(Settings(batch_window_ms=0), engine_factory=lambda s: engine)
    with LiveServer(app, http=deadline_protocol(HEADER_S, BODY_S)) as live:
        yield live


def _assert_408(answer, what: str, deadline_s: float, sent_s: float = 0.0) -> None:
    assert answer.status == 408, answer
    assert json.loads(answer.body.decode("utf-8"))["detail"].startswith(f"request {what} not complete within")
    assert answer.closed_after_s is not None, "the connection was left open"
    assert deadline_s - 0.05 <= answer.closed_after_s + sent_s <= deadline_s + SLACK_S, answer.closed_after_s


@pytest.mark.parametrize("name, pieces, what, deadline_s", [
    ("nothing sent", [b""], "headers", HEADER_S),
    ("half the headers", [REQUEST[:30]], "headers", HEADER_S),
    ("headers without their blank line", [REQUEST[:REQUEST.index(b"\r\n\r\n") + 2]], "headers", HEADER_S),
    ("half the body (Content-Length larger than sent)", [REQUEST[:-10]], "body", BODY_S),
    ("headers only", [REQUEST[:-len(GENERATE)]], "body", BODY_S),
])
def test_half_sent_requests_get_408_and_are_closed(server, name, pieces, what, deadline_s):
    answer = exchange(server.port, pieces, wait_s=5, until_closed=True)
    _assert_408(answer, what, deadline_s)


def test_dribbled_headers_do_not_extend_the_deadline(server):
    """A byte every 50 ms (slowloris): the deadline counts from the first byte, not the latest."""
    pieces = split(REQUEST[:REQUEST.index(b"\r\n\r\n")], 40)          # 2 s of dribbling, the deadline is 0.5 s
    answer = exchange(server.port, pieces, gap_s=0.05, wait_s=5, until_closed=True)
    assert answer.status == 408 and not answer.sent_all and answer.closed_after_s is not None


def test_a_slow_complete_request_inside_the_deadline_is_served(server):
    answer = exchange(server.port, split(REQUEST, 5), gap_s=HEADER_S / 10, wait_s=10)
    assert answer.status == 200 and len(json.loads(answer.body)["frames"]) == 20


def test_a_keep_alive_connection_gets_a_new_deadline_per_request(server):
    """One whole request answered, then (0.3 s later) half of the next: closed once the next request's own deadline
    passes, counted from its first byte (uvicorn's keep-alive timeout, 5 s, would close it only later)."""
    get = b"GET /health HTTP/1.1\r\nHost: t\r\n\r\n"
    answer = exchange(server.port, [get, get[:10]], gap_s=0.3, wait_s=5, until_closed=True)
    assert answer.status == 200          # the first answer; the 408 follows it
    assert answer.closed_after_s is not None and answer.closed_after_s <= HEADER_S + SLACK_S


def test_generation_time_is_not_timed(gate):
    """A generation longer than both deadlines is answered: only receiving the request is timed."""
    from t2m.service.app import create_app

    engine = FakeEngine(delay_s=2 * BODY_S)
    app = create_app(Settings(batch_window_ms=0), engine_factory=lambda s: engine)
    with LiveServer(app, http=deadline_protocol(HEADER_S, BODY_S)) as live:
        answer = exchange(live.port, [REQUEST], wait_s=10)
    assert answer.status == 200


def test_the_server_answers_while_connections_hang(server):
    with ThreadPoolExecutor(8) as pool:
        hanging = [pool.submit(exchange, server.port, [REQUEST[:20]], wait_s=5, until_closed=True) for _ in range(8)]
        assert httpx.get(server.url + "/health", timeout=2).status_code == 200
        assert httpx.post(server.url + "/generate", json=json.loads(GENERATE), timeout=5).status_code == 200
        for future in hanging:
            _assert_408(future.result(), "headers", HEADER_S)


def test_an_unparsable_request_is_a_json_400(server):
    answer = exchange(server.port, [b"GET / HTTP/1.1\r\nHost t\r\n\r\n"], wait_s=5)
    assert answer.status == 400 and answer.headers["content-type"] == "application/json"
    assert json.loads(answer.body.decode("utf-8"))["detail"]


def test_plain_uvicorn_keeps_half_sent_requests_open():
    """The control: without the service's protocol a connection with half its headers is still open 1.5 s (three
    header deadlines) later - uvicorn has no such deadline."""
    from t2m.service.app import create_app

    app = create_app(Settings(), engine_factory=lambda s: FakeEngine())
    with LiveServer(app, http="auto") as live:
        answer = exchange(live.port, [REQUEST[:30]], wait_s=3 * HEADER_S, until_closed=True)
    assert answer.status is None and answer.closed_after_s is None


def test_serve_runs_uvicorn_with_the_deadline_protocol(monkeypatch):
    """`t2m serve` names the protocol by import path (every worker loads it) and turns WebSockets off (the API has
    none: an Upgrade request gets the ordinary JSON answer)."""
    import uvicorn
    from uvicorn.importer import import_from_string

    from t2m.cli.main import main
    from t2m.service.request_deadlines import IMPORT_PATH, DeadlineHTTPProtocol
    from tests.service.conftest import free_port

    monkeypatch.setenv("T2M_BUNDLE_PATH", "restored-after-the-test")      # `serve --model` sets these for its workers
    monkeypatch.setenv("T2M_EXTRA_MODEL_DIRS", "restored-after-the-test")
    calls: list[dict] = []
    monkeypatch.setattr(uvicorn, "run", lambda *args, **kwargs: calls.append(kwargs))
    assert main(["serve", "--model", "default", "--port", str(free_port())]) == 0
    assert calls[-1]["http"] == IMPORT_PATH and calls[-1]["ws"] == "none"
    assert import_from_string(IMPORT_PATH) is DeadlineHTTPProtocol


def test_the_protocol_reads_its_deadlines_from_the_environment(monkeypatch):
    from t2m.service import request_deadlines

    monkeypatch.setenv("T2M_HEADER_TIMEOUT_S", "3.5")
    request_deadlines._timeouts_from_env.cache_clear()
    try:
        assert request_deadlines._timeouts_from_env() == (3.5, Settings().body_timeout_s)
    finally:
        request_deadlines._timeouts_from_env.cache_clear()
