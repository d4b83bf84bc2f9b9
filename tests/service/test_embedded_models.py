"""The committed second and third models (t2m/bundles/gpt, t2m/bundles/masked) served beside the default, as
scripts/serve.sh serves them: picked by the request's `model`, a 3-sentence stream in every format, the default
answering requests without `model`, and the shared text files of the embedded bundles."""
from __future__ import annotations

import numpy as np
import pytest

from t2m.bundles import DEFAULT_BUNDLE, EMBEDDED_BUNDLES
from t2m.service.settings import Settings

DEFAULT = "t2m-bandai-hifigpt-minilm"
MODELS = {"gpt": "t2m-bandai-minilm", "masked": "t2m-bandai-masked-minilm"}
# segment frames: duration x 20 fps rounded to the model's frames per code row (gpt and masked 4, hifigpt 8: 3 s -> 64)
SPANS = {"t2m-bandai-minilm": [(0, 60), (60, 100), (100, 140)],
         "t2m-bandai-masked-minilm": [(0, 60), (60, 100), (100, 140)],
         "t2m-bandai-hifigpt-minilm": [(0, 64), (64, 104), (104, 144)]}
STREAM = {"segments": [{"text": "a person walks forward", "duration": 3.0},
                       {"text": "a person waves with the right hand", "duration": 2.0},
                       {"text": "a person bows", "duration": 2.0}], "seed": 5}


@pytest.fixture(scope="module")
def served():
    from fastapi.testclient import TestClient

    from t2m.service.app import create_app
    from tests.service.conftest import wait_ready

    settings = Settings(bundle_path=DEFAULT_BUNDLE, extra_model_dirs=[EMBEDDED_BUNDLES[f] for f in MODELS],
                        intra_op_threads=1, batch_window_ms=0)
    with TestClient(create_app(settings)) as client:
        wait_ready(client)
        yield client


def test_health_lists_the_default_first_then_the_others(served):
    health = served.get("/health").json()
    names = [model["name"] for model in health["models"]]
    assert names == [DEFAULT, *MODELS.values()] and health["default"] == DEFAULT
    for model, family in zip(health["models"][1:], MODELS):
        assert model["extra"]["family"] == family and model["extra"]["unknown_text"]["detection"] == "warn"


@pytest.mark.parametrize("name", MODELS.values())
def test_a_three_sentence_stream(served, name):
    response = served.post("/generate", json={**STREAM, "model": name})
    assert response.status_code == 200, response.text
    body = response.json()
    assert body["model"]["name"] == name
    frames = np.asarray(body["frames"])
    assert frames.shape == (SPANS[name][-1][1], 22, 3) and np.isfinite(frames).all()
    assert [(s["start_frame"], s["end_frame"]) for s in body["segments"]] == SPANS[name]
    head, pelvis = frames[:, 15, 1], frames[:, 0, 1]
    assert (head > pelvis + 0.3).all(), f"{name}: the body is not upright"


@pytest.mark.parametrize("name", MODELS.values())
@pytest.mark.parametrize("fmt, media_type", [("bvh", "text/plain"), ("glb", "model/gltf-binary")])
def test_the_file_formats(served, name, fmt, media_type):
    response = served.post("/generate", json={**STREAM, "model": name, "format": fmt})
    assert response.status_code == 200 and response.headers["content-type"].startswith(media_type)
    assert len(response.content) > 1000


def test_the_default_answers_without_model_and_seeds_repeat(served):
    first = served.post("/generate", json=STREAM).json()
    assert first["model"]["name"] == DEFAULT
    assert [(s["start_frame"], s["end_frame"]) for s in first["segments"]] == SPANS[DEFAULT]
    for name in MODELS.values():
        again = served.post("/generate", json={**STREAM, "model": name}).json()
        once = served.post("/generate", json={**STREAM, "model": name}).json()
        assert again["frames"] == once["frames"]


@pytest.mark.parametrize("folder", MODELS)
def test_shared_text_files_are_links_to_the_default_bundle(folder):
    """The embedded bundles use the default's text encoder, tokenizer and caption index: one copy on disk (links),
    each bundle still verified by its own manifest's hashes (the service loads through the link)."""
    from t2m.export.writing.verify import verify_bundle

    bundle = EMBEDDED_BUNDLES[folder]
    for name in ("text_encoder.onnx", "tokenizer.json", "caption_index.npz"):
        path = bundle / name
        assert path.is_symlink() and path.resolve() == (DEFAULT_BUNDLE / name).resolve(), name
    verify_bundle(bundle)
