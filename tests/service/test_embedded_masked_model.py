"""The committed masked model (t2m/bundles/masked) served beside the default, as scripts/serve.sh serves them: picked
by the request's `model`, a 3-sentence stream in every format, the default answering requests without `model`."""
from __future__ import annotations

import numpy as np
import pytest

from t2m.bundles import DEFAULT_BUNDLE, EMBEDDED_BUNDLES
from t2m.service.settings import Settings

MASKED = "t2m-bandai-masked-minilm"
STREAM = {"segments": [{"text": "a person walks forward", "duration": 3.0},
                       {"text": "a person waves with the right hand", "duration": 2.0},
                       {"text": "a person bows", "duration": 2.0}], "seed": 5}


@pytest.fixture(scope="module")
def both_models():
    from fastapi.testclient import TestClient

    from t2m.service.app import create_app
    from tests.service.conftest import wait_ready

    settings = Settings(bundle_path=DEFAULT_BUNDLE, extra_model_dirs=[EMBEDDED_BUNDLES["masked"]],
                        intra_op_threads=1, batch_window_ms=0)
    with TestClient(create_app(settings)) as client:
        wait_ready(client)
        yield client


def test_health_lists_the_default_first_and_the_masked_model(both_models):
    health = both_models.get("/health").json()
    names = [model["name"] for model in health["models"]]
    assert names == ["t2m-bandai-minilm", MASKED] and health["default"] == "t2m-bandai-minilm"
    masked = health["models"][1]
    assert masked["extra"]["family"] == "masked" and masked["extra"]["unknown_text"]["detection"] == "warn"


def test_a_three_sentence_stream_from_the_masked_model(both_models):
    response = both_models.post("/generate", json={**STREAM, "model": MASKED})
    assert response.status_code == 200, response.text
    body = response.json()
    assert body["model"]["name"] == MASKED
    frames = np.asarray(body["frames"])
    assert frames.shape == (140, 22, 3) and np.isfinite(frames).all()
    assert [(s["start_frame"], s["end_frame"]) for s in body["segments"]] == [(0, 60), (60, 100), (100, 140)]
    head, pelvis = frames[:, 15, 1], frames[:, 0, 1]
    assert (head > pelvis + 0.3).all(), "the masked model's body is not upright"


@pytest.mark.parametrize("fmt, media_type", [("bvh", "text/plain"), ("glb", "model/gltf-binary")])
def test_the_masked_model_answers_in_the_file_formats(both_models, fmt, media_type):
    response = both_models.post("/generate", json={**STREAM, "model": MASKED, "format": fmt})
    assert response.status_code == 200 and response.headers["content-type"].startswith(media_type)
    assert len(response.content) > 1000


def test_the_default_answers_without_model_and_seeds_repeat(both_models):
    first = both_models.post("/generate", json=STREAM).json()
    assert first["model"]["name"] == "t2m-bandai-minilm"
    again = both_models.post("/generate", json={**STREAM, "model": MASKED}).json()
    once = both_models.post("/generate", json={**STREAM, "model": MASKED}).json()
    assert again["frames"] == once["frames"]
