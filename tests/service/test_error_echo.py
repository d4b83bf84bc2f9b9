"""Error answers echo what the client sent as valid UTF-8 JSON, whatever it sent (a lone surrogate in a text
was a 500). The hostile-input corpus against a real server is tests/fuzz/test_hostile_inputs.py (slow suite)."""
from __future__ import annotations

import json

import pytest
from fastapi import HTTPException

from t2m.service.safe_json import MAX_ECHO_DEPTH, TOO_DEEP, json_safe
from t2m.service.settings import Settings
from tests.fuzz.hostile_check import strict_json  # UTF-8 JSON read strictly: no escaped lone surrogate either
from tests.service.fakes import FakeEngine

JSON = {"content-type": "application/json"}


@pytest.fixture(scope="module")
def client():
    from fastapi.testclient import TestClient

    from t2m.service.app import create_app
    from tests.service.conftest import wait_ready

    app = create_app(Settings(), engine_factory=lambda s: FakeEngine())

    @app.get("/echo-detail")
    def echo_detail() -> None:   # an HTTPException whose detail carries client text
        raise HTTPException(400, detail={"text": "\ud800 walk", "raw": b"\xff"})

    with TestClient(app, raise_server_exceptions=False) as test_client:
        wait_ready(test_client)
        yield test_client


def _fields(detail: list[dict]) -> set[str]:
    return {".".join(str(part) for part in error["loc"][1:]) or "body" for error in detail}


@pytest.mark.parametrize("body, field", [
    (rb'{"segments":[{"text":"\ud800 walk","duration":2}]}', "segments.0.text"),          # the request
    (rb'{"segments":[{"text":"\ud800 walk","duration":0.1}]}', "segments.0.text"),        # with another error
    (rb'{"segments":[{"text":"\udc00\ud800","duration":2}]}', "segments.0.text"),         # a reversed pair
    (rb'{"segments":[{"text":"walk","duration":2}],"model":"\udfff"}', "model"),
    (rb'{"segments":[{"text":"walk","duration":2}],"format":"\ud800"}', "format"),
    (rb'{"segments":[{"text":"walk","duration":2}],"\ud800":1}', "body"),                 # a surrogate key
    (rb'{"segments":[{"text":"walk","duration":2}],"x\ud800":["\udfff"]}', "body"),
    (rb'{"segments":[{"text":"walk","duration":2,"note":"\ud800"}]}', "segments.0.note"),
])
def test_lone_surrogates_are_a_422_naming_the_field(client, body, field):
    response = client.post("/generate", content=body, headers=JSON)
    assert response.status_code == 422, response.text
    assert field in _fields(strict_json(response.content)["detail"])


def test_a_surrogate_pair_is_text(client):
    """A pair escaped in JSON is one character (here an emoji): a normal request."""
    response = client.post("/generate", content=rb'{"segments":[{"text":"\ud83d\ude00 walk","duration":2}]}',
                           headers=JSON)
    assert response.status_code == 200 and strict_json(response.content)["segments"][0]["text"] == "\U0001f600 walk"


@pytest.mark.parametrize("body, content_type", [
    (b'\xff\xfe{"segments"', "text/plain"),
    (b'\xff\xfe{"segments"', None),
    (b"a=\xff&b=\xc0\xaf", "application/x-www-form-urlencoded"),
    (b"\x00\x01\xff", "application/octet-stream"),
])
def test_bytes_that_are_no_utf8_are_echoed_escaped(client, body, content_type):
    headers = {"content-type": content_type} if content_type else {}
    response = client.post("/generate", content=body, headers=headers)
    assert response.status_code == 422, response.text
    (error,) = strict_json(response.content)["detail"]
    assert error["loc"] == ["body"] and "\\xff" in error["input"]


@pytest.mark.parametrize("depth", [300, 600, 900])
def test_deep_nesting_is_echoed_cut(client, depth):
    """Deeper than the encoders recurse (once a 500), shallower than the JSON parser refuses (400)."""
    body = b'{"segments":[{"text":' + b"[" * depth + b"]" * depth + b',"duration":2}]}'
    response = client.post("/generate", content=body, headers=JSON)
    assert response.status_code == 422
    (error,) = strict_json(response.content)["detail"]
    assert error["loc"] == ["body", "segments", 0, "text"] and TOO_DEEP in json.dumps(error["input"])


def test_http_exception_details_are_made_safe(client):
    response = client.get("/echo-detail")
    assert response.status_code == 400
    assert strict_json(response.content) == {"detail": {"text": "\\ud800 walk", "raw": "\\xff"}}


def test_json_safe():
    assert json_safe({"\ud800": ["a\udfffb", b"\xffok", float("nan"), float("-inf"), 1.5, 2**64, None, True]}) == {
        "\\ud800": ["a\\udfffb", "\\xffok", "nan", "-inf", 1.5, 2**64, None, True]}
    assert json_safe(("x", {1, 2})) in (["x", [1, 2]], ["x", [2, 1]])
    nested: list = []
    for _ in range(2 * MAX_ECHO_DEPTH):
        nested = [nested]
    text = json.dumps(json_safe(nested), allow_nan=False)
    assert text.count("[") == MAX_ECHO_DEPTH and TOO_DEEP in text
    assert json_safe(ValueError("\ud800")) == {}              # FastAPI's encoding of an exception in a `ctx`

    class Unprintable:   # FastAPI's encoder gives up on it (no __dict__, not iterable), and str() fails too
        __slots__ = ()

        def __str__(self) -> str:
            raise RuntimeError("no")

    assert json_safe(Unprintable()) == "<Unprintable>"
