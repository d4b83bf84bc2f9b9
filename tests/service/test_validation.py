"""Every request rule of POST /generate answers 422 naming the field (schema-level rules need no real model)."""
from __future__ import annotations

import pytest

from t2m.api import GenerateRequest, to_generation_request
from t2m.runtime.types import frames_for_duration, tokens_for_duration
from t2m.service.settings import Settings
from tests.service.fakes import FakeEngine

OK = {"text": "a person walks forward", "duration": 3.0}


@pytest.fixture(scope="module")
def client():
    from fastapi.testclient import TestClient

    from t2m.service.app import create_app
    from tests.service.conftest import wait_ready

    with TestClient(create_app(Settings(), engine_factory=lambda s: FakeEngine())) as test_client:
        wait_ready(test_client)
        yield test_client


def _locs(response) -> list[list]:
    return [error["loc"] for error in response.json()["detail"]]


@pytest.mark.parametrize("body, loc", [
    ({"segments": []}, ["body", "segments"]),
    ({"segments": [OK] * 33}, ["body", "segments"]),
    ({}, ["body", "segments"]),
    ({"segments": [{"text": "", "duration": 2}]}, ["body", "segments", 0, "text"]),
    ({"segments": [OK, {"text": "   \t ", "duration": 2}]}, ["body", "segments", 1, "text"]),
    ({"segments": [{"text": "x" * 301, "duration": 2}]}, ["body", "segments", 0, "text"]),
    ({"segments": [{"text": 5, "duration": 2}]}, ["body", "segments", 0, "text"]),
    ({"segments": [{"duration": 2}]}, ["body", "segments", 0, "text"]),
    ({"segments": [{"text": "walk", "duration": 0.4}]}, ["body", "segments", 0, "duration"]),
    ({"segments": [{"text": "walk", "duration": 10.5}]}, ["body", "segments", 0, "duration"]),
    ({"segments": [{"text": "walk", "duration": -1}]}, ["body", "segments", 0, "duration"]),
    ({"segments": [{"text": "walk", "duration": "long"}]}, ["body", "segments", 0, "duration"]),
    ({"segments": [{"text": "walk", "duration": "3"}]}, ["body", "segments", 0, "duration"]),       # no coercion
    ({"segments": [OK], "guidance": False}, ["body", "guidance"]),
    ({"segments": [OK], "seed": True}, ["body", "seed"]),
    ({"segments": [OK], "top_k": "5"}, ["body", "top_k"]),
    ({"segments": [{"text": ["walk"], "duration": 2}]}, ["body", "segments", 0, "text"]),
    ({"segments": {"text": "walk"}}, ["body", "segments"]),
    ({"segments": [{"text": "walk", "duration": 2, "speed": 1}]}, ["body", "segments", 0, "speed"]),
    ({"segments": [{"text": "walk", "duration": 10}] * 13}, ["body", "segments"]),          # 130 s > 120 s
    ({"segments": [{"text": "walk", "duration": 10}] * 12 + [{"text": "then"}]}, ["body", "segments"]),  # null = 10 s
    ({"segments": [OK], "format": "fbx"}, ["body", "format"]),
    ({"segments": [OK], "seed": -1}, ["body", "seed"]),
    ({"segments": [OK], "seed": 2**53}, ["body", "seed"]),
    ({"segments": [OK], "seed": 1.5}, ["body", "seed"]),
    ({"segments": [OK], "guidance": -0.1}, ["body", "guidance"]),
    ({"segments": [OK], "guidance": 10.5}, ["body", "guidance"]),
    ({"segments": [OK], "temperature": 0}, ["body", "temperature"]),
    ({"segments": [OK], "temperature": -1}, ["body", "temperature"]),
    ({"segments": [OK], "temperature": 50}, ["body", "temperature"]),
    ({"segments": [OK], "top_k": 0}, ["body", "top_k"]),
    ({"segments": [OK], "top_k": 65}, ["body", "top_k"]),                                     # fake codebook: 64
    ({"segments": [OK], "model": "other"}, ["body", "model"]),
])
def test_each_rule_answers_422_naming_the_field(client, body, loc):
    response = client.post("/generate", json=body)
    assert response.status_code == 422, response.text
    assert loc in _locs(response), response.json()
    assert all(error["msg"] for error in response.json()["detail"])


@pytest.mark.parametrize("body", [
    {"segments": [{"text": "walk", "duration": 0.5}]},
    {"segments": [{"text": "walk", "duration": 10}] * 12},                                   # exactly 120 s
    {"segments": [{"text": "x" * 300, "duration": None}], "top_k": 64, "guidance": 0, "temperature": 5},
    {"segments": [{"text": "  padded  "}] * 12, "guidance": 10, "seed": 2**53 - 1},
    {"segments": [OK], "seed": 4.0, "top_k": 3.0},                  # JSON Schema integers may be written 4.0
])
def test_limits_themselves_are_accepted(client, body):
    response = client.post("/generate", json=body)
    assert response.status_code == 200, response.text


def test_nan_is_refused(client):
    response = client.post("/generate", content=b'{"segments": [{"text": "walk", "duration": NaN}]}',
                           headers={"content-type": "application/json"})
    assert response.status_code == 422


@pytest.mark.parametrize("raw", [b"{not json", b"", b"[1, 2]", b'"text"', b"\xff\xfe"])
def test_malformed_json_is_a_4xx_without_traceback(client, raw):
    response = client.post("/generate", content=raw, headers={"content-type": "application/json"})
    assert 400 <= response.status_code < 500
    assert "Traceback" not in response.text


def test_text_is_trimmed():
    request = GenerateRequest.model_validate({"segments": [{"text": "  walk  "}]})
    assert request.segments[0].text == "walk"


@pytest.mark.parametrize("duration, decoded, frames", [(0.5, 8, 10), (1.0, 20, 20), (2.0, 40, 40), (2.3, 48, 46),
                                                       (0.7, 16, 14), (3.0, 60, 60), (10.0, 200, 200)])
def test_frame_formula(duration, decoded, frames):
    """A model of 4 frames a step decodes whole steps; the answer has exactly round(duration * 20) frames."""
    assert tokens_for_duration(duration) * 4 == round(duration * 20 / 4) * 4 == decoded
    assert frames_for_duration(duration) == round(duration * 20) == frames


def test_defaults_come_from_the_model():
    from tests.service.fakes import FAKE_LIMITS

    request = GenerateRequest.model_validate({"segments": [OK]})
    assert request.format == "json" and request.temperature == 1.0 and request.top_k is None
    assert to_generation_request(request, FAKE_LIMITS, seed=3).guidance == FAKE_LIMITS.default_guidance
    no_uncond = FAKE_LIMITS.__class__(**{**FAKE_LIMITS.__dict__, "unconditional_branch": False})
    assert to_generation_request(request, no_uncond, seed=3).guidance == 1.0
    explicit = GenerateRequest.model_validate({"segments": [OK], "guidance": 2.0})
    assert to_generation_request(explicit, no_uncond, seed=3).guidance == 2.0


def test_openapi_is_generated_from_the_schemas(client):
    schema = client.get("/openapi.json").json()
    body = schema["paths"]["/generate"]["post"]["requestBody"]["content"]["application/json"]["schema"]
    assert body["$ref"].endswith("/GenerateRequest")
    request_schema = schema["components"]["schemas"]["GenerateRequest"]
    assert request_schema["additionalProperties"] is False
    assert set(request_schema["properties"]) == {"segments", "format", "seed", "guidance", "temperature", "top_k",
                                                 "model", "stream"}
    assert "MotionResponse" in schema["components"]["schemas"]
    answers = schema["paths"]["/generate"]["post"]["responses"]["200"]["content"]
    assert set(answers) == {"application/json", "text/plain", "model/gltf-binary", "application/x-ndjson"}


def test_model_limits_resolve_the_guidance_default():
    from t2m.runtime.types import ModelLimits

    guided = ModelLimits(name="m", version="1", fps=20, frames_per_token=4, max_tokens=50, codebook_size=512,
                         default_guidance=3.0, unconditional_branch=True)
    unguided = ModelLimits(name="m", version="1", fps=20, frames_per_token=4, max_tokens=50, codebook_size=512,
                           default_guidance=3.0, unconditional_branch=False)
    assert guided.guidance() == 3.0 and guided.guidance(1.5) == 1.5
    assert unguided.guidance() == 1.0 and unguided.guidance(2.0) == 2.0
