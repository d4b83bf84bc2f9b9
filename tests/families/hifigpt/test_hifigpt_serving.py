"""The service serving a T2M-HiFiGPT bundle: the contract (manifest, graphs, parity in the card), the engine's two-tier
loop (a stream's code maps concatenated and decoded once, free lengths ended by the stop head, seeds that do not
depend on the batch, the same codes as the PyTorch reference), and HTTP end to end in json, bvh and glb (ASGI client
and a real uvicorn)."""
from __future__ import annotations

import json

import httpx
import numpy as np
import pytest

from t2m.runtime.types import GenerationRequest, RequestLimitError, SegmentRequest
from tests.service.conftest import LiveServer

STREAM = [("a person walks forward", 1.2), ("a person waves with the right hand", 0.8), ("a person bows", 2.0)]
STEPS = [3, 2, 5]   # round(duration * 20 / 8)


@pytest.fixture(scope="module")
def engine(hifigpt_bundle):
    from t2m.runtime.engine import OnnxEngine

    return OnnxEngine.load(hifigpt_bundle, intra_op_threads=1)


def _request(segments, seed=7, guidance=3.0, top_k=None, temperature=1.0) -> GenerationRequest:
    return GenerationRequest(segments=[SegmentRequest(text, duration) for text, duration in segments], seed=seed,
                             guidance=guidance, top_k=top_k, temperature=temperature)


@pytest.fixture
def decoded(engine, monkeypatch) -> list[np.ndarray]:
    """The code maps each decoder call receives."""
    calls: list[np.ndarray] = []
    original = engine.decoder.decode
    monkeypatch.setattr(engine.decoder, "decode", lambda codes: calls.append(np.asarray(codes)) or original(codes))
    return calls


def test_the_bundle_states_its_family_graphs_and_parity(hifigpt_bundle):
    from t2m.bundle import read_manifest
    from t2m.export.writing.verify import verify_bundle

    raw = verify_bundle(hifigpt_bundle)
    assert raw["family"] == "hifigpt" and raw["frames_per_token"] == 8 and raw["residual_layers"] == 3
    assert {"temporal_step.onnx", "residual_step.onnx", "decoder.onnx"} <= set(raw["files"])
    assert "gpt_step.onnx" not in raw["files"]
    manifest = read_manifest(hifigpt_bundle)
    assert manifest.family == "hifigpt" and type(manifest.settings).__name__ == "HiFiGPTSettings"
    assert manifest.default_guidance == 3.0 and manifest.length_conditioning and manifest.unconditional_branch
    card = (hifigpt_bundle / "MODEL_CARD.md").read_text()
    assert "codes and stops identical True" in card


@pytest.mark.parametrize("change, message", [
    (lambda m: m["hifigpt"].update(block_size=3), "'hifigpt.block_size' 3 is smaller than max_tokens + 1"),
    (lambda m: m["hifigpt"].pop("n_layer_residual"), "missing field 'hifigpt.n_layer_residual'"),
    (lambda m: m.update(residual_layers=4), "temporal_step.onnx: input 'codes' has size 3 on axis 1"),
])
def test_broken_manifests_are_refused_naming_the_field(hifigpt_bundle, tmp_path, change, message):
    import shutil

    from t2m.bundle import BundleError
    from t2m.runtime.bundle_loader import load_bundle

    copy = tmp_path / "broken"
    shutil.copytree(hifigpt_bundle, copy)
    manifest = json.loads((copy / "manifest.json").read_text())
    change(manifest)
    (copy / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(BundleError, match=message.replace("(", r"\(").replace("+", r"\+")):
        load_bundle(copy, intra_op_threads=1)


def test_a_stream_is_one_decode_of_the_concatenated_code_maps(engine, decoded):
    motion = engine.generate(_request(STREAM))
    assert len(decoded) == 1 and decoded[0].shape == (sum(STEPS), 3)
    assert [(s.start_frame, s.end_frame) for s in motion.segments] == [(0, 24), (24, 40), (40, 80)]
    assert motion.joints.shape == (80, 22, 3) and np.isfinite(motion.joints).all() and motion.tokens == 10


def test_served_codes_equal_the_pytorch_reference(engine, decoded, hifigpt_build):
    from t2m.decoding.lockstep import SamplingJob
    from t2m.families.hifigpt.loop import sample_code_rows
    from t2m.families.hifigpt.random_bundle import random_hifigpt_models
    from t2m.families.hifigpt.sampling import TorchResidualGptStep, TorchTemporalStep

    segments = [*STREAM[:2], ("a person bows", None)]
    engine.generate(_request(segments, seed=5, guidance=2.5, top_k=6))
    model = random_hifigpt_models(**hifigpt_build)["model"]
    job = SamplingJob(conds=engine.text.encode([text for text, _ in segments]), targets=[3, 2, None], guidance=2.5,
                      temperature=1.0, top_k=6, rng=np.random.default_rng(5))
    (reference,) = sample_code_rows(TorchTemporalStep(model), TorchResidualGptStep(model), [job], max_tokens=25)
    assert reference is not None
    np.testing.assert_array_equal(decoded[0], np.concatenate(reference))


def test_a_null_duration_ends_on_the_stop_head_with_the_seed(engine):
    segments = [STREAM[0], ("a person bows", None)]
    first, again = engine.generate(_request(segments, seed=4)), engine.generate(_request(segments, seed=4))
    span = first.segments[1]
    assert first.segments[0].end_frame == 24 and span.start_frame == 24
    assert 8 <= span.end_frame - span.start_frame <= 25 * 8 and (span.end_frame - span.start_frame) % 8 == 0
    np.testing.assert_array_equal(first.joints, again.joints)


def test_the_same_seed_gives_the_same_motion_alone_or_batched(engine):
    alone = engine.generate(_request(STREAM, seed=11))
    others = [_request([("someone jumps", None)], seed=1), _request(STREAM[:1], seed=2, guidance=1.0, top_k=3)]
    batched = engine.generate_batch([others[0], _request(STREAM, seed=11), others[1]])
    np.testing.assert_array_equal(batched[1].joints, alone.joints)
    assert not np.array_equal(engine.generate(_request(STREAM, seed=12)).joints, alone.joints)


def test_request_limits_name_the_field(engine):
    with pytest.raises(RequestLimitError, match=r"top_k: must be 1\.\.16, got 17"):
        engine.generate(_request(STREAM, top_k=17))
    with pytest.raises(RequestLimitError, match=r"^segments\.0\.duration: needs 26 tokens"):
        engine.generate(_request([("a person walks", 10.4)]))


def _check_formats(post) -> None:
    body = {"segments": [{"text": text, "duration": duration} for text, duration in STREAM], "seed": 3}
    answer = post(body)
    assert answer.status_code == 200, answer.text
    data = answer.json()
    assert np.asarray(data["frames"]).shape == (80, 22, 3)
    assert [s["end_frame"] for s in data["segments"]] == [24, 40, 80]
    bvh = post({**body, "format": "bvh"})
    assert bvh.status_code == 200 and bvh.text.startswith("HIERARCHY")
    glb = post({**body, "format": "glb"})
    assert glb.status_code == 200 and glb.content[:4] == b"glTF"
    free = post({**body, "segments": [{"text": "a person bows", "duration": None}]})
    assert free.status_code == 200 and len(free.json()["frames"]) % 8 == 0


def test_the_api_answers_json_bvh_and_glb(hifigpt_bundle, make_client):
    from t2m.service.settings import Settings

    client = make_client(Settings(bundle_path=hifigpt_bundle, intra_op_threads=1))
    _check_formats(lambda body: client.post("/generate", json=body))
    refused = client.post("/generate", json={"segments": [{"text": "walk", "duration": 1.0}], "top_k": 17})
    assert refused.status_code == 422 and "top_k" in refused.text
    model = client.get("/health").json()["model"]
    assert model["default_guidance"] == 3.0
    assert model["extra"]["family"] == "hifigpt" and model["extra"]["hifigpt"]["n_layer_temporal"] == 2


def test_a_real_server_answers_json_bvh_and_glb(hifigpt_bundle):
    from t2m.service.app import create_app
    from t2m.service.settings import Settings

    app = create_app(Settings(bundle_path=hifigpt_bundle, intra_op_threads=1))
    with LiveServer(app) as server, httpx.Client(base_url=server.url, timeout=30) as http:
        _check_formats(lambda body: http.post("/generate", json=body))


def test_gpt_and_hifigpt_bundles_served_together(random_bundle, hifigpt_bundle, make_client):
    from t2m.service.settings import Settings

    client = make_client(Settings(bundle_path=random_bundle, extra_model_dirs=[hifigpt_bundle], intra_op_threads=1))
    body = {"segments": [{"text": text, "duration": duration} for text, duration in STREAM], "seed": 3}
    hifi = client.post("/generate", json={**body, "model": "t2m-random-hifigpt-test"})
    assert hifi.status_code == 200 and [s["end_frame"] for s in hifi.json()["segments"]] == [24, 40, 80]
    gpt = client.post("/generate", json=body)
    assert gpt.status_code == 200 and [s["end_frame"] for s in gpt.json()["segments"]] == [24, 40, 80]
    families = [m.get("extra", {}).get("family", "gpt") for m in client.get("/health").json()["models"]]
    assert families == ["gpt", "hifigpt"]
