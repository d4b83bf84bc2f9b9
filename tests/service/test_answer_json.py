"""The json answers and stream lines (t2m/runtime/formats.py) are written by orjson: the same numbers, byte for byte,
as json.dumps wrote them, and text orjson refuses (a lone surrogate) still gives valid JSON."""
from __future__ import annotations

import json

import numpy as np

from t2m.runtime.formats import frames_json, ndjson, stream_frames


def test_frames_are_the_bytes_json_dumps_wrote():
    joints = np.random.default_rng(0).normal(size=(40, 22, 3)).astype(np.float32) * 3
    message = {**stream_frames(8, joints), "note": "ascii only"}
    as_lists = {**message, "frames": message["frames"].tolist()}
    assert ndjson(message) == json.dumps(as_lists, separators=(",", ":")).encode() + b"\n"
    assert json.loads(ndjson(message))["frames"] == frames_json(joints).tolist()


def test_a_lone_surrogate_still_gives_valid_json():
    message = {"type": "error", "detail": "segments.0.text: \ud800 is no text", "values": [1.5, -0.0]}
    line = ndjson(message)
    assert line.endswith(b"\n") and json.loads(line) == message
    frames = stream_frames(0, np.ones((2, 22, 3), np.float32))    # frames beside such text: through json.dumps too
    assert json.loads(ndjson({**frames, "note": "\ud800"}))["frames"] == frames["frames"].tolist()
