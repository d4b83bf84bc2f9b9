"""The service serving a masked-family bundle (MoMask / MoGenTS token maps): the loader accepts it, the engine samples
every segment's map through t2m.families.masked.loop with the request's own generator, concatenates the maps along time
and
decodes once; the API answers json/bvh/glb as for the GPT; tokens equal the PyTorch reference for a fixed seed."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from t2m.runtime.types import GenerationRequest, RequestLimitError, SegmentRequest

STREAM = [("a person walks forward", 1.0), ("a person waves with the right hand", 0.8), ("a person bows", 0.6)]


@pytest.fixture(scope="module")
def masked_1d_bundle(tmp_path_factory) -> Path:
    """MoMask's variant without a length estimator."""
    from t2m.families.masked.random_bundle import build_random_masked_bundle

    return build_random_masked_bundle(tmp_path_factory.mktemp("masked") / "1d", variant="1d", residual_layers=2,
                                      length_estimator=False)


@pytest.fixture(scope="module")
def engine(masked_bundle):
    from t2m.runtime.engine import OnnxEngine

    return OnnxEngine.load(masked_bundle, intra_op_threads=1)


def _request(segments, seed=7, guidance=4.0, top_k=None) -> GenerationRequest:
    return GenerationRequest(segments=[SegmentRequest(text, duration) for text, duration in segments], seed=seed,
                             guidance=guidance, top_k=top_k)


@pytest.fixture
def decoded(engine, monkeypatch) -> list[np.ndarray]:
    """The code maps each decoder call receives."""
    calls: list[np.ndarray] = []
    original = engine.decoder.decode

    def record(codes):
        calls.append(np.asarray(codes))
        return original(codes)

    monkeypatch.setattr(engine.decoder, "decode", record)
    return calls


def test_both_variants_load_and_verify(masked_bundle, masked_1d_bundle):
    from t2m.export.writing.verify import verify_bundle
    from t2m.runtime.engine import OnnxEngine

    for bundle in (masked_bundle, masked_1d_bundle):
        verify_bundle(bundle)
        loaded = OnnxEngine.load(bundle, intra_op_threads=1)
        assert loaded.bundle.manifest.family == "masked"
        assert loaded.limits.default_guidance == 4.0 and loaded.limits.codebook_size == 16
    assert loaded.continuous() is None   # not autoregressive: its batches run whole, no step to join


def test_a_stream_is_one_decode_of_the_concatenated_maps(engine, decoded):
    motion = engine.generate(_request(STREAM))
    rows = [5, 4, 3]  # round(duration * 20 / 4)
    assert len(decoded) == 1
    assert decoded[0].shape == (sum(rows), 6, 2)
    assert [(s.start_frame, s.end_frame) for s in motion.segments] == [(0, 20), (20, 36), (36, 48)]
    assert motion.joints.shape == (48, 22, 3) and np.isfinite(motion.joints).all()
    assert motion.tokens == sum(rows)


def test_the_same_seed_gives_the_same_motion_alone_or_batched(engine):
    alone = engine.generate(_request(STREAM, seed=11))
    others = [_request([("someone jumps", 2.0)], seed=1), _request(STREAM[:1], seed=2, guidance=1.0)]
    batched = engine.generate_batch([others[0], _request(STREAM, seed=11), others[1]])
    np.testing.assert_array_equal(batched[1].joints, alone.joints)
    assert not np.array_equal(engine.generate(_request(STREAM, seed=12)).joints, alone.joints)


def test_served_tokens_equal_the_pytorch_reference(engine, decoded, masked_build):
    from t2m.families.masked.random_bundle import random_masked_models
    from t2m.families.masked.sampling import generate_token_maps

    models = random_masked_models(**{k: v for k, v in masked_build.items() if k != "steps"})
    engine.generate(_request(STREAM, seed=5, guidance=3.0))
    conds = engine.text.encode([text for text, _ in STREAM])
    rows = [5, 4, 3]
    reference = generate_token_maps(models["masked"], models["residual"], conds, rows, steps=4, guidance=3.0,
                                    residual_guidance=5.0, rng=np.random.default_rng(5))
    expected = np.concatenate([reference[i, :n] for i, n in enumerate(rows)])
    np.testing.assert_array_equal(decoded[0], expected)


def test_top_k_is_checked_against_the_codebook(engine):
    with pytest.raises(RequestLimitError, match=r"top_k: must be 1\.\.16, got 17"):
        engine.generate(_request(STREAM, top_k=17))
    assert engine.generate(_request(STREAM, top_k=1)).joints.shape[0] == 48


def test_a_null_duration_is_drawn_from_the_length_graph_with_the_seed(engine):
    segments = [STREAM[0], ("a person bows", None)]
    first, again = engine.generate(_request(segments, seed=4)), engine.generate(_request(segments, seed=4))
    span = first.segments[1]
    assert first.segments[0].end_frame == 20 and span.start_frame == 20
    assert 4 <= span.end_frame - span.start_frame <= 50 * 4 and (span.end_frame - span.start_frame) % 4 == 0
    np.testing.assert_array_equal(first.joints, again.joints)


def test_a_null_duration_without_a_length_graph_is_refused(masked_1d_bundle):
    from t2m.runtime.engine import OnnxEngine

    engine = OnnxEngine.load(masked_1d_bundle, intra_op_threads=1)
    with pytest.raises(RequestLimitError, match=r"^segments\.1\.duration: model .* has no length estimator"):
        engine.generate(_request([STREAM[0], ("a person bows", None)]))
    assert engine.generate(_request(STREAM)).joints.shape == (48, 22, 3)


def test_the_api_answers_json_bvh_and_glb(masked_bundle, make_client):
    from t2m.service.settings import Settings

    client = make_client(Settings(bundle_path=masked_bundle, intra_op_threads=1))
    body = {"segments": [{"text": text, "duration": duration} for text, duration in STREAM], "seed": 3}
    answer = client.post("/generate", json=body)
    assert answer.status_code == 200, answer.text
    data = answer.json()
    assert np.asarray(data["frames"]).shape == (48, 22, 3)
    assert [s["end_frame"] for s in data["segments"]] == [20, 36, 48]
    bvh = client.post("/generate", json={**body, "format": "bvh"})
    assert bvh.status_code == 200 and bvh.text.startswith("HIERARCHY")
    glb = client.post("/generate", json={**body, "format": "glb"})
    assert glb.status_code == 200 and glb.content[:4] == b"glTF"
    refused = client.post("/generate", json={**body, "top_k": 17})
    assert refused.status_code == 422 and "top_k" in refused.text
    model = client.get("/health").json()["model"]
    assert model["default_guidance"] == 4.0
    assert model["extra"]["family"] == "masked" and model["extra"]["masked"]["columns"] == 6


def test_the_api_refuses_a_null_duration_without_a_length_graph(masked_1d_bundle, make_client):
    from t2m.service.settings import Settings

    client = make_client(Settings(bundle_path=masked_1d_bundle, intra_op_threads=1))
    answer = client.post("/generate", json={"segments": [{"text": "a person walks", "duration": 1.0},
                                                         {"text": "a person bows", "duration": None}], "seed": 1})
    assert answer.status_code == 422 and "segments.1.duration" in answer.text


def test_a_gpt_and_a_masked_bundle_served_together(random_bundle, masked_bundle, make_client):
    """The default GPT bundle and a masked one side by side: the request's model picks the family's loop."""
    from t2m.service.settings import Settings

    client = make_client(Settings(bundle_path=random_bundle, extra_model_dirs=[masked_bundle], intra_op_threads=1))
    body = {"segments": [{"text": text, "duration": duration} for text, duration in STREAM], "seed": 3}
    masked = client.post("/generate", json={**body, "model": "t2m-random-masked-test"})
    assert masked.status_code == 200, masked.text
    assert masked.json()["model"]["name"] == "t2m-random-masked-test"
    assert [s["end_frame"] for s in masked.json()["segments"]] == [20, 36, 48]
    gpt = client.post("/generate", json=body)
    assert gpt.status_code == 200 and gpt.json()["model"]["name"] != "t2m-random-masked-test"
    families = [m.get("extra", {}).get("family", "gpt") for m in client.get("/health").json()["models"]]
    assert families == ["gpt", "masked"]


def test_the_1d_variant_serves_the_pytorch_reference_tokens(masked_1d_bundle, monkeypatch):
    from t2m.families.masked.random_bundle import random_masked_models
    from t2m.families.masked.sampling import generate_token_maps
    from t2m.runtime.engine import OnnxEngine

    engine = OnnxEngine.load(masked_1d_bundle, intra_op_threads=1)
    calls: list[np.ndarray] = []
    original = engine.decoder.decode
    monkeypatch.setattr(engine.decoder, "decode", lambda codes: calls.append(np.asarray(codes)) or original(codes))
    motion = engine.generate(_request(STREAM, seed=9, guidance=2.0))
    models = random_masked_models(variant="1d", residual_layers=2, length_estimator=False, seed=0)
    conds = engine.text.encode([text for text, _ in STREAM])
    reference = generate_token_maps(models["masked"], models["residual"], conds, [5, 4, 3], steps=4, guidance=2.0,
                                    residual_guidance=5.0, rng=np.random.default_rng(9))
    expected = np.concatenate([reference[i, :n] for i, n in enumerate([5, 4, 3])])
    assert calls[0].shape == (12, 1, 2) and motion.joints.shape == (48, 22, 3)
    np.testing.assert_array_equal(calls[0], expected)
