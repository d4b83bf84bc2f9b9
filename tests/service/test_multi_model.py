"""Several models in one service: the request's `model` picks a bundle by its manifest name, each model has its own
engine and batcher, /health and /metrics list and label each, duplicate names are refused at load."""
from __future__ import annotations

import shutil
import threading
import time
from dataclasses import replace
from pathlib import Path

import pytest

from t2m.service.settings import Settings
from tests.service.fakes import FAKE_LIMITS, FakeEngine

A, B = "t2m-random-test", "t2m-random-b"           # tests/service/conftest.py: random_bundle, second_bundle
BODY = {"segments": [{"text": "a person walks forward", "duration": 3.0},
                     {"text": "a person waves", "duration": 2.0}], "seed": 11}


@pytest.fixture(scope="module")
def two_models(random_bundle, second_bundle):
    """The real OnnxEngine on two random bundles: A (the default; codebook 32, 50 tokens, guidance 3) and
    B (codebook 64, 25 tokens = 5 s, guidance 2)."""
    from fastapi.testclient import TestClient

    from t2m.service.app import create_app
    from tests.service.conftest import wait_ready

    settings = Settings(bundle_path=random_bundle, extra_model_dirs=[second_bundle], intra_op_threads=1,
                        batch_window_ms=0)
    with TestClient(create_app(settings)) as client:
        wait_ready(client)
        yield client


def _post(client, **changes):
    return client.post("/generate", json={**BODY, **changes})


def _ok(client, **changes) -> dict:
    response = _post(client, **changes)
    assert response.status_code == 200, response.text
    return response.json()


def test_the_request_picks_a_model_by_name_and_the_default_answers_without_one(two_models):
    assert _ok(two_models, model=B)["model"] == {"name": B, "version": "0.0.1"}
    default = _ok(two_models)
    assert default["model"] == {"name": A, "version": "0.0.0"}
    assert _ok(two_models, model=A)["frames"] == default["frames"]
    assert _ok(two_models, model=B)["frames"] != default["frames"]
    bvh = _post(two_models, model=B, format="bvh")
    assert bvh.status_code == 200 and bvh.text.startswith("HIERARCHY")


def test_an_unknown_model_is_422_naming_model_and_listing_the_names(two_models):
    response = _post(two_models, model="t2m-nope")
    assert response.status_code == 422
    [error] = response.json()["detail"]
    assert error["loc"] == ["body", "model"]
    assert "t2m-nope" in error["msg"] and A in error["msg"] and B in error["msg"]
    for bad in ("", 3, ["t2m-random-b"]):
        refused = _post(two_models, model=bad)
        assert refused.status_code == 422 and refused.json()["detail"][0]["loc"][:2] == ["body", "model"], bad


def test_the_chosen_models_limits_apply(two_models):
    refused = _post(two_models, top_k=40)                                   # A's codebook: 32
    assert refused.status_code == 422 and refused.json()["detail"][0]["loc"] == ["body", "top_k"]
    assert "32" in refused.json()["detail"][0]["msg"]
    assert _ok(two_models, model=B, top_k=40)["model"]["name"] == B         # B's codebook: 64
    too_big = _post(two_models, model=B, top_k=65)
    assert too_big.status_code == 422 and "64" in too_big.json()["detail"][0]["msg"]

    long = [{"text": "a person walks", "duration": 8.0}]                    # 40 tokens: A makes 50, B 25
    assert _ok(two_models, segments=long)["segments"][0]["end_frame"] == 160
    short = _post(two_models, model=B, segments=long)
    assert short.status_code == 422
    assert short.json()["detail"][0]["loc"] == ["body", "segments", 0, "duration"]
    assert "25" in short.json()["detail"][0]["msg"]

    assert _ok(two_models, model=B, guidance=None)["frames"] == _ok(two_models, model=B, guidance=2.0)["frames"]
    assert _ok(two_models, guidance=None)["frames"] == _ok(two_models, guidance=3.0)["frames"]


def test_health_lists_every_model_with_the_default_first(two_models):
    health = two_models.get("/health").json()
    assert health["status"] == "ok" and health["default"] == A
    assert [m["name"] for m in health["models"]] == [A, B]
    assert health["model"] == health["models"][0]                          # the default, as before
    assert [m["codebook_size"] for m in health["models"]] == [32, 64]
    assert [m["max_tokens"] for m in health["models"]] == [50, 25]
    assert all(m["extra"]["load_seconds"] >= 0 for m in health["models"])


def test_metrics_label_each_model(two_models):
    def tokens(text: str, model: str) -> float:
        prefix = f't2m_tokens_generated_total{{model="{model}"}} '
        return float(next(row for row in text.splitlines() if row.startswith(prefix)).split()[-1])

    before = two_models.get("/metrics").text
    _ok(two_models)                                                         # 25 tokens (3 s + 2 s)
    _ok(two_models, model=B, segments=[{"text": "a person walks", "duration": 1.0}])   # 5 tokens
    after = two_models.get("/metrics").text
    assert tokens(after, A) - tokens(before, A) == 25 and tokens(after, B) - tokens(before, B) == 5
    for name, version in ((A, "0.0.0"), (B, "0.0.1")):
        assert f't2m_model_info{{name="{name}",version="{version}"}} 1.0' in after
        assert f't2m_queue_depth{{model="{name}"}} 0.0' in after and f't2m_in_flight{{model="{name}"}}' in after
        assert f't2m_segments_generated_total{{model="{name}"}}' in after


def test_a_busy_model_changes_nothing_of_another_models_motion(two_models):
    """Same request + seed to A: the same motion alone and while B is busy with a stream of long requests."""
    alone = _ok(two_models, seed=5)["frames"]
    stop = threading.Event()
    served: list[int] = []

    def keep_b_busy(seed: int) -> None:
        while not stop.is_set():
            served.append(_post(two_models, model=B, seed=seed, segments=[
                {"text": f"a person runs {i}", "duration": 5.0} for i in range(6)]).status_code)

    workers = [threading.Thread(target=keep_b_busy, args=(seed,)) for seed in (1, 2)]
    for worker in workers:
        worker.start()
    try:
        while not served:
            time.sleep(0.01)
        busy = [_ok(two_models, seed=5)["frames"] for _ in range(3)]
    finally:
        stop.set()
        for worker in workers:
            worker.join(30)
    assert all(frames == alone for frames in busy)
    assert set(served) == {200}


class _RecordingEngine(FakeEngine):
    """A FakeEngine under its own name that records the texts of every batch it runs."""

    def __init__(self, name: str, gate: threading.Event | None = None) -> None:
        super().__init__(limits=replace(FAKE_LIMITS, name=name), gate=gate)
        self.texts: list[list[str]] = []

    def generate_batch(self, requests):
        self.texts.append([r.segments[0].text for r in requests])
        return super().generate_batch(requests)


def _factory(engines: dict[str, FakeEngine]):
    """An engine_factory giving each bundle directory (settings.bundle_path) its own engine."""
    return lambda settings: engines[settings.bundle_path.name]


def test_each_model_has_its_own_queue_so_a_blocked_model_does_not_block_another(make_client, tmp_path):
    gate = threading.Event()
    engines = {"a": _RecordingEngine("fake-a", gate=gate), "b": _RecordingEngine("fake-b")}
    client = make_client(Settings(bundle_path=tmp_path / "a", extra_model_dirs=[tmp_path / "b"], batch_window_ms=50),
                         engine_factory=_factory(engines))
    body = {"segments": [{"text": "for a", "duration": 1.0}], "seed": 1}
    waiting = threading.Thread(target=lambda: client.post("/generate", json=body))
    waiting.start()                                                         # A's worker is held at the gate
    while not engines["a"].batches:
        time.sleep(0.005)
    started = time.perf_counter()
    answers = [client.post("/generate", json={**body, "model": "fake-b", "segments": [
        {"text": "for b", "duration": 1.0}]}) for _ in range(2)]
    assert [a.status_code for a in answers] == [200, 200] and time.perf_counter() - started < 5
    assert {a.json()["model"]["name"] for a in answers} == {"fake-b"}
    metrics = client.get("/metrics").text
    assert 't2m_in_flight{model="fake-a"} 1.0' in metrics and 't2m_in_flight{model="fake-b"} 0.0' in metrics
    gate.set()
    waiting.join(10)
    assert all(texts == ["for a"] * len(texts) for texts in engines["a"].texts)   # never a batch shared with B
    assert all(texts == ["for b"] * len(texts) for texts in engines["b"].texts)


def test_health_is_ok_only_once_every_bundle_has_loaded(make_client, tmp_path):
    release = threading.Event()
    engines = {"a": _RecordingEngine("fake-a"), "b": _RecordingEngine("fake-b")}

    def factory(settings):
        if settings.bundle_path.name == "b":
            release.wait(10)
        return engines[settings.bundle_path.name]

    client = make_client(Settings(bundle_path=tmp_path / "a", extra_model_dirs=[tmp_path / "b"]),
                         engine_factory=factory, ready=False)
    time.sleep(0.1)                                                         # A has loaded by now, B waits
    loading = client.get("/health")
    assert loading.status_code == 503 and loading.json()["status"] == "loading"
    assert client.post("/generate", json=BODY).status_code == 503
    release.set()
    deadline = time.perf_counter() + 10
    while client.get("/health").status_code != 200 and time.perf_counter() < deadline:
        time.sleep(0.01)
    assert [m["name"] for m in client.get("/health").json()["models"]] == ["fake-a", "fake-b"]


def _wait_for_error(client) -> dict:
    deadline = time.perf_counter() + 20
    while client.get("/health").json()["status"] == "loading" and time.perf_counter() < deadline:
        time.sleep(0.02)
    health = client.get("/health")
    assert health.status_code == 503 and "Retry-After" in health.headers
    return health.json()


def test_two_bundles_with_the_same_name_are_refused_at_load(make_client, random_bundle, tmp_path):
    twin = tmp_path / "twin"
    shutil.copytree(random_bundle, twin)
    client = make_client(Settings(bundle_path=random_bundle, extra_model_dirs=[twin], intra_op_threads=1),
                         ready=False)
    health = _wait_for_error(client)
    assert health["status"] == "error"
    assert f"'{A}'" in health["detail"] and str(twin) in health["detail"] and str(random_bundle) in health["detail"]
    assert "own manifest name" in health["detail"]
    assert client.post("/generate", json=BODY).status_code == 503


def test_a_broken_extra_bundle_fails_the_load_naming_it(make_client, random_bundle, tmp_path):
    client = make_client(Settings(bundle_path=random_bundle, extra_model_dirs=[tmp_path / "missing"],
                                  intra_op_threads=1), ready=False)
    health = _wait_for_error(client)
    assert health["status"] == "error" and "missing" in health["detail"]


def test_one_bundle_serves_as_before(make_client, tmp_path):
    client = make_client(Settings(bundle_path=tmp_path / "a"), engine_factory=_factory({"a": FakeEngine()}))
    health = client.get("/health").json()
    assert health["default"] == "fake" and [m["name"] for m in health["models"]] == ["fake"]
    assert health["model"] == health["models"][0]
    assert client.post("/generate", json={**BODY, "model": "fake"}).status_code == 200
    assert client.post("/generate", json={**BODY, "model": "other"}).json()["detail"][0]["loc"] == ["body", "model"]


def test_extra_model_dirs_from_the_environment(monkeypatch):
    monkeypatch.setenv("T2M_BUNDLE_PATH", "/models/main")
    monkeypatch.setenv("T2M_EXTRA_MODEL_DIRS", "/models/b, /models/c,")
    settings = Settings()
    assert settings.model_dirs == [Path("/models/main"), Path("/models/b"), Path("/models/c")]
    one = settings.for_bundle(settings.extra_model_dirs[0])
    assert one.bundle_path == Path("/models/b") and one.extra_model_dirs == []
    assert one.max_queue == settings.max_queue
    monkeypatch.delenv("T2M_EXTRA_MODEL_DIRS")
    assert Settings().extra_model_dirs == []


def test_serve_with_repeated_model_sets_the_default_and_the_extras(monkeypatch, random_bundle, second_bundle):
    import uvicorn

    from t2m.cli.main import main
    from tests.service.conftest import free_port

    monkeypatch.setenv("T2M_BUNDLE_PATH", "restored-after-the-test")      # `serve --model` sets these for its workers
    monkeypatch.setenv("T2M_EXTRA_MODEL_DIRS", "restored-after-the-test")
    seen: list[Settings] = []
    monkeypatch.setattr(uvicorn, "run", lambda *args, **kwargs: seen.append(Settings()))
    assert main(["serve", "--model", str(random_bundle), "--model", str(second_bundle),
                 "--port", str(free_port())]) == 0
    assert seen[-1].bundle_path == random_bundle.resolve()
    assert seen[-1].extra_model_dirs == [second_bundle.resolve()]
    assert main(["serve", "--model", str(second_bundle), "--port", str(free_port())]) == 0
    assert seen[-1].model_dirs == [second_bundle.resolve()]                 # one --model: that model alone


def test_serve_refuses_two_bundles_with_the_same_name(monkeypatch, capsys, random_bundle, tmp_path):
    from t2m.cli.main import main

    monkeypatch.setenv("T2M_BUNDLE_PATH", "restored-after-the-test")
    monkeypatch.setenv("T2M_EXTRA_MODEL_DIRS", "restored-after-the-test")
    twin = tmp_path / "twin"
    shutil.copytree(random_bundle, twin)
    assert main(["serve", "--model", str(random_bundle), "--model", str(twin)]) == 2
    error = capsys.readouterr().err
    assert "both named" in error and A in error and len(error.strip().splitlines()) == 1


def test_sdk_sends_model_only_when_named_and_reads_the_models(tmp_path):
    import asyncio
    import json

    import httpx

    from t2m.client import AsyncT2MClient, Health, T2MClient

    bodies: list[dict] = []
    motion = {"fps": 20, "joints": ["pelvis"], "parents": [-1], "frames": [[[0.0, 0.0, 0.0]]],
              "segments": [{"text": "walk", "start_frame": 0, "end_frame": 1}], "seed": 1,
              "model": {"name": B, "version": "0.0.1"}, "warnings": []}
    health = {"status": "ok", "service_version": "9", "model": {"name": A}, "models": [{"name": A}, {"name": B}],
              "default": A, "a_field_from_a_newer_server": 1}

    def answer(request: httpx.Request) -> httpx.Response:
        if request.url.path == "/health":
            return httpx.Response(200, json=health)
        bodies.append(json.loads(request.content))
        if bodies[-1]["format"] == "bvh":
            return httpx.Response(200, text="HIERARCHY", headers={"X-Seed": "1"})
        return httpx.Response(200, json=motion)

    with T2MClient(transport=httpx.MockTransport(answer)) as t2m:
        assert t2m.health().model_names == [A, B] and t2m.health().default == A
        assert t2m.generate("walk", model=B).model.name == B
        t2m.generate("walk")
        t2m.generate_bvh("walk", model=B)
    assert [body.get("model", "absent") for body in bodies] == [B, "absent", B]

    async def scenario(path) -> None:
        async with AsyncT2MClient(transport=httpx.MockTransport(answer)) as t2m:
            assert (await t2m.health()).models[1]["name"] == B
            await t2m.generate("walk", model=A)
            await t2m.save_bvh(path, "walk", model=B)

    bodies.clear()
    asyncio.run(scenario(tmp_path / "b.bvh"))
    assert [body["model"] for body in bodies] == [A, B]
    legacy = Health.from_json({"status": "ok", "model": {"name": "old"}})   # a server from before `models`
    assert legacy.model_names == ["old"] and legacy.models == [] and legacy.default is None
