"""An imported bundle served beside the default model (t2m/bundles/default) in one service, as
`t2m serve --model default --model IMPORTED` runs it: the request's `model` picks the import for a 3-sentence
stream (json and `"stream": true`), whose frames are that bundle's own motion for the seed, and the default model
still answers requests without `model`."""
from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np

from t2m.runtime.types import GenerationRequest, SegmentRequest, frames_for_duration
from tests.service.conftest import DEFAULT_MODEL, wait_ready
from tests.service.test_streaming_http import ROUNDING, check_stream_equals_answer, messages

Segments = list[tuple[str, float | None]]
THREE_SENTENCES: Segments = [("a person walks forward", 2.0), ("a person waves with the right hand", 1.2),
                             ("a person bows", None)]


def check_spans(answer: dict, segments: Segments) -> None:
    """Contiguous spans from frame 0 to the last frame, one per sentence; a fixed duration's span is exactly
    round(duration * 20) frames, a free one whole codes of 4 frames, at least one."""
    frames = np.asarray(answer["frames"])
    spans = [(s["start_frame"], s["end_frame"]) for s in answer["segments"]]
    assert [s["text"] for s in answer["segments"]] == [text for text, _ in segments]
    assert spans[0][0] == 0 and spans[-1][1] == len(frames)
    assert all(end == start for (_, end), (start, _) in itertools.pairwise(spans))
    for (start, end), (_, duration) in zip(spans, segments):
        if duration is None:
            assert end - start >= 4 and (end - start) % 4 == 0
        else:
            assert end - start == frames_for_duration(duration)
    assert frames.shape[1:] == (22, 3) and np.isfinite(frames).all()


def served_alone(bundle: Path, segments: Segments, seed: int) -> np.ndarray:
    """The bundle's own motion for the request (its engine, no HTTP), at its default guidance."""
    from t2m.runtime.engine import OnnxEngine

    engine = OnnxEngine.load(bundle, intra_op_threads=1)
    request = GenerationRequest(segments=[SegmentRequest(t, d) for t, d in segments], seed=seed,
                                guidance=engine.limits.default_guidance)
    return engine.generate(request).joints


def check_beside_default(bundle: Path, segments: Segments = THREE_SENTENCES, seed: int = 5) -> None:
    from fastapi.testclient import TestClient

    from t2m.service.app import create_app
    from t2m.service.settings import Settings

    name = json.loads((bundle / "manifest.json").read_text())["name"]
    default = json.loads((DEFAULT_MODEL / "manifest.json").read_text())["name"]
    settings = Settings(bundle_path=DEFAULT_MODEL, extra_model_dirs=[bundle], intra_op_threads=1)
    body = {"segments": [{"text": text, "duration": duration} for text, duration in segments], "seed": seed}
    with TestClient(create_app(settings)) as client:
        wait_ready(client, timeout_s=60)
        assert [m["name"] for m in client.get("/health").json()["models"]] == [default, name]
        imported = client.post("/generate", json={**body, "model": name})
        assert imported.status_code == 200, imported.text
        answer = imported.json()
        assert answer["model"]["name"] == name and answer["seed"] == seed
        check_spans(answer, segments)
        assert np.abs(np.asarray(answer["frames"]) - served_alone(bundle, segments, seed)).max() <= ROUNDING
        # a GPT model's early frames come from a window of its codes: onnxruntime rounds ~1e-6 differently from the
        # whole decode, and the root's integration carries that along (random weights drift metres away)
        tolerance = ROUNDING + 1e-5 * max(1.0, float(np.abs(np.asarray(answer["frames"])).max()))
        check_stream_equals_answer(messages(client.post("/generate", json={**body, "model": name, "stream": True})),
                                   answer, tolerance)
        plain = client.post("/generate", json=body)
        assert plain.status_code == 200, plain.text
        assert plain.json()["model"]["name"] == default
        check_spans(plain.json(), segments)
