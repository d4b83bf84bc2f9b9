"""The HTTP checks every served family must pass on a multi-sentence request (the fourth family's test and the
diffusion family's): exact spans, finite frames, same seed same motion, another seed another one, and the NDJSON
stream giving the whole answer's frames, segments and frame count."""
from __future__ import annotations

import json
from typing import Any

import numpy as np


def check_whole_and_streamed(client: Any, body: dict, spans: list[tuple[int, int]]) -> tuple[dict, list[np.ndarray]]:
    """POST /generate `body` whole and streamed; returns the whole answer and the streamed frame chunks."""
    whole = client.post("/generate", json=body)
    assert whole.status_code == 200, whole.text
    answer = whole.json()
    assert [(s["start_frame"], s["end_frame"]) for s in answer["segments"]] == spans
    frames = np.asarray(answer["frames"])
    assert frames.shape == (spans[-1][1], 22, 3) and np.isfinite(frames).all()
    assert client.post("/generate", json=body).json()["frames"] == answer["frames"]        # same seed, same motion
    assert client.post("/generate", json={**body, "seed": 12}).json()["frames"] != answer["frames"]

    streamed = client.post("/generate", json={**body, "stream": True})
    assert streamed.status_code == 200 and streamed.headers["content-type"].startswith("application/x-ndjson")
    messages = [json.loads(line) for line in streamed.text.splitlines() if line]
    assert messages[0]["type"] == "start" and messages[-1]["type"] == "end"
    chunks = [np.asarray(m["frames"]) for m in messages if m["type"] == "frames"]
    np.testing.assert_allclose(np.concatenate(chunks), frames, atol=2e-5)
    assert messages[-1]["segments"] == answer["segments"] and messages[-1]["frame_count"] == spans[-1][1]
    return answer, chunks
