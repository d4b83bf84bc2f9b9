"""The committed second and third models (t2m/bundles/gpt, t2m/bundles/masked) served beside the default, as
scripts/serve.sh serves them: picked by the request's `model`, a 3-sentence stream in every format, the default
answering requests without `model`, what /health tells a client to plan a request, and the shared text files of the
embedded bundles."""
from __future__ import annotations

import re

import numpy as np
import pytest

from t2m.bundles import DEFAULT_BUNDLE, EMBEDDED_BUNDLES
from t2m.service.settings import Settings

DEFAULT = "t2m-bandai-hifigpt-minilm"
MODELS = {"gpt": "t2m-bandai-minilm", "masked": "t2m-bandai-masked-minilm"}
# segment frames: exactly duration x 20 fps, whatever the model's frames per code row (gpt and masked 4, hifigpt 8:
# 3 s decodes 64 frames, fitted to 60)
SPANS = {name: [(0, 60), (60, 100), (100, 140)] for name in (DEFAULT, *MODELS.values())}
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


def test_health_says_what_a_request_may_ask_of_each_model(served):
    """Frames per step, the longest segment, the duration range, whether a null duration is allowed and how the model
    ends it, and the request limits, per model."""
    models = {model["name"]: model for model in served.get("/health").json()["models"]}
    for name, per_token, ends in [(DEFAULT, 8, "its stop head"), (MODELS["gpt"], 4, "its End token"),
                                  (MODELS["masked"], 4, "a length drawn from its length estimator")]:
        model = models[name]
        assert model["fps"] == 20 and model["frames_per_token"] == per_token
        assert model["max_segment_seconds"] == model["max_tokens"] * per_token / 20 == 10.0
        assert model["limits"] == {"max_segments": 32, "max_text_chars": 300, "min_duration_s": 0.5,
                                   "max_duration_s": 10.0, "null_duration": True, "null_duration_ends_by": ends,
                                   "max_total_s": 120.0, "max_guidance": 10.0, "max_temperature": 5.0,
                                   "max_top_k": model["codebook_size"], "max_seed": 2**53 - 1,
                                   "max_body_bytes": 65536, "request_timeout_s": 60.0}


@pytest.mark.parametrize("name", [DEFAULT, *MODELS.values()])
@pytest.mark.parametrize("fmt, media_type", [("bvh", "text/plain"), ("glb", "model/gltf-binary")])
def test_the_file_formats_hold_the_exact_frames(served, name, fmt, media_type):
    """3 + 2 + 2 s: 140 frames in the BVH and the glb too, 8 frames a step or 4 (they are made from the json joints)."""
    from t2m.motion.gltf import glb_joint_positions

    response = served.post("/generate", json={**STREAM, "model": name, "format": fmt})
    assert response.status_code == 200 and response.headers["content-type"].startswith(media_type)
    if fmt == "bvh":
        assert re.search(r"^Frames:\s*(\d+)$", response.text, re.MULTILINE).group(1) == "140"
    else:
        assert len(glb_joint_positions(response.content)) == 140


def test_the_default_answers_without_model_and_seeds_repeat(served):
    first = served.post("/generate", json=STREAM).json()
    assert first["model"]["name"] == DEFAULT and len(first["frames"]) == 140
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
