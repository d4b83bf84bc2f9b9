"""Property-based fuzzing of the HTTP API from its own OpenAPI schema (schemathesis) against a live loopback server.

Every operation gets valid and invalid requests generated from the published schema; every answer must be no 5xx,
with a documented status code, content type, headers and body shape (response conformance); what the schema forbids
must be refused and requests without the API key must get 401. The number of examples is bounded
(T2M_FUZZ_EXAMPLES, default 60 per operation).

One schemathesis check is replaced by a narrower one: a JSON schema cannot state cross-field or model-dependent
limits (total duration <= 120 s, stream only with the json format, top_k <= the model's codebook, a segment's tokens
<= the model's maximum) nor the names of the models a server loaded (`model`), so a schema-valid request may get
422 - but only for one of those rules, each named in the answer.
"""
from __future__ import annotations

import os
from pathlib import Path

import pytest
import schemathesis
from hypothesis import HealthCheck, settings
from schemathesis import GenerationMode
from schemathesis.checks import positive_data_acceptance

from t2m.testing.server_process import running_server

pytestmark = pytest.mark.slow

MAX_EXAMPLES = int(os.environ.get("T2M_FUZZ_EXAMPLES", "60"))
# The published schema declares bearer auth on POST /generate, so the server runs with a key (as in production) and
# schemathesis checks that requests without it are refused.
API_KEY = "fuzz-test-key"
AUTH = {"Authorization": f"Bearer {API_KEY}"}
# The rules beyond the schema (service/schemas.py model_limit_errors, unknown_model_error, the total-duration and the
# stream-only-as-json validators).
# POST /edit: a handle is opaque to the schema (its checks, t2m/runtime/handles.py, all name `handle`), and so are
# the edits' limits that depend on it (a segment it lacks, the edited motion's length, the family's edit kinds).
# An uploaded `motion`: one source of joints or bvh, one of handle or motion, what the frames and segments make, the
# BVH text and skeleton, a model without an encoder graph (t2m/runtime/uploads.py).
RULES_BEYOND_SCHEMA = ("total duration", "codebook size", "this model makes at most", "no model named",
                       "only the json format streams", "handle", "the edited motion would", "the edits it supports",
                       "edited twice", "exactly one", "goes with `joints`", "joints; model", "fps last",
                       "the segments cover", "code steps", "not a BVH file", "skeleton", "pose",
                       "cannot encode uploaded motions", "frame rates of", "a motion needs at least")


def _published_schema() -> dict:
    """The OpenAPI document the service publishes; building the app loads no model (that happens at startup)."""
    from t2m.service.app import create_app
    from t2m.service.settings import Settings

    return create_app(Settings(bundle_path=Path("unused-at-schema-time"))).openapi()


# Built at import (cheap), not from a fixture: schemathesis' from_fixture does not work with pytest 9.
schema = schemathesis.openapi.from_dict(_published_schema())


@pytest.fixture(scope="module")
def live_url(tmp_path_factory):
    torch = pytest.importorskip("torch")
    torch.set_num_threads(1)
    from t2m.families.gpt.random_bundle import build_random_bundle

    bundle = build_random_bundle(tmp_path_factory.mktemp("bundle") / "tiny")
    # a body limit above the schema's largest upload (120 s x 120 fps of joints): a schema-violating body reaches
    # validation (a 422) instead of the body limit (a 413, tested in tests/service/test_http_behaviour.py and the
    # uploads' tests)
    with running_server(bundle, env={"T2M_API_KEY": API_KEY, "T2M_MAX_BODY_BYTES": str(64 * 2**20)},
                        log_dir=tmp_path_factory.mktemp("server")) as server:
        yield server.url


@schema.parametrize()
@settings(max_examples=MAX_EXAMPLES, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much, HealthCheck.data_too_large])
def test_api_conforms_to_its_schema(case, live_url):
    response = case.call(base_url=live_url, headers=AUTH, timeout=120)
    case.validate_response(response, headers=AUTH, excluded_checks=[positive_data_acceptance])

    positive = case.meta is not None and case.meta.generation.mode == GenerationMode.POSITIVE
    if positive and response.status_code == 422:
        messages = [item.get("msg", "") for item in response.json()["detail"]]
        assert messages and all(any(rule in m for rule in RULES_BEYOND_SCHEMA) for m in messages), (
            f"schema-valid request refused for a reason the schema does not state: {messages}\n"
            f"body: {case.body!r}")
