"""POST /generate through the ASGI app on the real OnnxEngine (tiny random bundle): formats, seeds, segments."""
from __future__ import annotations

from itertools import pairwise

import numpy as np
import pytest

BODY = {"segments": [{"text": "a person walks forward", "duration": 3.0},
                     {"text": "a person waves with the right hand", "duration": 2.0}],
        "seed": 123, "guidance": 3.0, "temperature": 1.0, "top_k": None}


def _json(app_client, **changes) -> dict:
    response = app_client.post("/generate", json={**BODY, **changes})
    assert response.status_code == 200, response.text
    return response.json()


def test_json_answer_layout(app_client):
    response = app_client.post("/generate", json=BODY)
    assert response.status_code == 200
    assert response.headers["content-type"] == "application/json"
    assert response.headers["X-Seed"] == "123"
    data = response.json()
    assert set(data) == {"fps", "joints", "parents", "frames", "segments", "seed", "model", "warnings", "handle"}
    assert data["handle"].startswith("t2m1.")   # POST /edit takes it back (tests/service/test_edit.py)
    assert data["fps"] == 20 and len(data["joints"]) == 22 and data["joints"][0] == "pelvis"
    assert data["parents"][:4] == [-1, 0, 0, 0]
    frames = np.asarray(data["frames"])
    assert frames.shape == (100, 22, 3) and np.isfinite(frames).all()
    assert data["seed"] == 123 and data["model"] == {"name": "t2m-random-test", "version": "0.0.0"}
    assert data["warnings"] == []


@pytest.mark.parametrize("durations", [(3.0, 2.0), (0.5, 0.7, 2.3, 10.0), (1.1, None, 4.9)])
def test_segment_boundaries(app_client, durations):
    segments = [{"text": f"sentence {i}", "duration": d} for i, d in enumerate(durations)]
    data = _json(app_client, segments=segments)
    spans = data["segments"]
    assert [s["text"] for s in spans] == [f"sentence {i}" for i in range(len(durations))]
    assert spans[0]["start_frame"] == 0
    for span, following in pairwise(spans):
        assert span["end_frame"] == following["start_frame"]              # contiguous
    for span, duration in zip(spans, durations):
        length = span["end_frame"] - span["start_frame"]
        if duration is None:
            assert length % 4 == 0 and 4 <= length <= 200
        else:
            assert length == round(duration * 20)   # exact, though the model makes 4 frames a step
    assert spans[-1]["end_frame"] == len(data["frames"])


def test_same_seed_same_motion_different_seed_differs(app_client):
    first, again, other = _json(app_client), _json(app_client), _json(app_client, seed=124)
    assert first["frames"] == again["frames"]
    assert first["frames"] != other["frames"]


def test_no_seed_returns_a_reusable_seed(app_client):
    free = _json(app_client, seed=None)
    assert isinstance(free["seed"], int) and 0 <= free["seed"] < 2**31
    replay = _json(app_client, seed=free["seed"])
    assert replay["frames"] == free["frames"]
    assert _json(app_client, seed=None)["seed"] != free["seed"]          # collision chance 2**-31


def test_seed_header_for_files(app_client):
    response = app_client.post("/generate", json={**BODY, "seed": None, "format": "bvh"})
    assert response.status_code == 200
    seed = int(response.headers["X-Seed"])
    replay = app_client.post("/generate", json={**BODY, "seed": seed, "format": "bvh"})
    assert replay.content == response.content


def test_bvh_answer_round_trips_through_forward_kinematics(app_client):
    from t2m.motion.bvh import read_bvh
    from t2m.motion.bvh_export import bvh_joint_names
    from t2m.motion.skeleton import SMPL22

    response = app_client.post("/generate", json={**BODY, "format": "bvh"})
    assert response.status_code == 200
    assert response.headers["content-type"].startswith("text/plain")
    assert response.headers["content-disposition"] == 'attachment; filename="motion.bvh"'
    bvh = read_bvh(response.text)
    joints = np.asarray(_json(app_client)["frames"])
    assert bvh.num_frames == len(joints) and abs(bvh.frame_time - 0.05) < 1e-6
    order = [bvh.joint_index(name) for name in bvh_joint_names(SMPL22)]   # BVH order is depth-first
    positions = bvh.forward_kinematics()[:, order] / 100.0                # the exporter writes centimetres
    assert positions.shape == joints.shape
    error = np.linalg.norm(positions - joints, axis=-1).mean()
    assert error < 0.02, f"mean joint error {error * 100:.2f} cm"


def test_glb_answer(app_client):
    from t2m.motion.gltf import glb_joint_positions

    response = app_client.post("/generate", json={**BODY, "format": "glb"})
    assert response.status_code == 200
    assert response.headers["content-type"] == "model/gltf-binary"
    assert response.headers["content-disposition"] == 'attachment; filename="motion.glb"'
    assert response.content[:4] == b"glTF"
    positions = glb_joint_positions(response.content)
    joints = np.asarray(_json(app_client)["frames"])
    assert positions.shape == joints.shape
    assert np.linalg.norm(positions - joints, axis=-1).mean() < 0.02


def test_model_limits_are_422(app_client):
    response = app_client.post("/generate", json={**BODY, "top_k": 33})            # codebook of 32
    assert response.status_code == 422
    assert response.json()["detail"][0]["loc"] == ["body", "top_k"]
    assert "32" in response.json()["detail"][0]["msg"]
    assert _json(app_client, top_k=32)["frames"]


def test_guidance_default_and_warning_header(app_client, make_client, bundle_without_uncond):
    from t2m.service.settings import Settings

    default = _json(app_client, guidance=None)
    assert default["frames"] == _json(app_client, guidance=3.0)["frames"]          # manifest default_guidance 3.0
    client = make_client(Settings(bundle_path=bundle_without_uncond, intra_op_threads=1))
    plain = client.post("/generate", json={**BODY, "guidance": None})
    assert plain.status_code == 200 and plain.json()["warnings"] == []             # defaults to 1: no warning
    forced = client.post("/generate", json={**BODY, "guidance": 2.0, "format": "bvh"})
    assert forced.status_code == 200 and "unconditional branch" in forced.headers["X-T2M-Warnings"]
    flagged = client.post("/generate", json={**BODY, "guidance": 2.0}).json()
    assert "unconditional branch" in flagged["warnings"][0]


def test_health_reports_the_model(app_client):
    health = app_client.get("/health")
    assert health.status_code == 200
    model = health.json()["model"]
    assert model["name"] == "t2m-random-test" and model["codebook_size"] == 32 and model["max_tokens"] == 50
    assert model["default_guidance"] == 3.0 and model["extra"]["license"] == "Apache-2.0"


def test_metrics_count_tokens(app_client):
    before = app_client.get("/metrics").text
    _json(app_client)                                                              # 25 tokens
    after = app_client.get("/metrics").text

    def tokens(text: str) -> float:
        line = next(row for row in text.splitlines() if row.startswith("t2m_tokens_generated_total"))
        return float(line.split()[-1])

    assert tokens(after) - tokens(before) == 25


def test_viewer_is_served(app_client):
    response = app_client.get("/")
    assert response.status_code == 200 and "<html" in response.text.lower()
    assert app_client.get("/static/viewer/main.js").status_code == 200
