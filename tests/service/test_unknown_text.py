"""Knowing what it does not know: the caption index, its calibrated threshold, and the warnings (or 422s) it gives."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from t2m.bundle import BundleError, CaptionIndex
from t2m.runtime.types import GenerationRequest, RequestLimitError, SegmentRequest


def _tiny_phrasings(folder: Path) -> Path:
    """A calibration/evaluation file of two known and two unknown sentences (for `t2m index-captions`)."""
    path = folder / "phrasings.json"
    path.write_text(json.dumps({name: {"known": ["a person walks forward", "someone waves"],
                                       "unknown": ["a cat purrs", "rain falls"]}
                                for name in ("calibration", "evaluation")}))
    return path


def _request(*texts: str, seed: int = 0) -> GenerationRequest:
    return GenerationRequest([SegmentRequest(text, 2.0) for text in texts], seed=seed, guidance=1.0)


def test_index_round_trip_and_nearest(tmp_path):
    rng = np.random.default_rng(0)
    features = rng.normal(size=(50, 16)).astype(np.float32)
    captions = [f"caption {i}" for i in range(50)]
    index = CaptionIndex.build(captions, features)
    index.save(tmp_path / "index.npz")
    loaded = CaptionIndex.load(tmp_path / "index.npz", dim=16)
    assert loaded.captions == index.captions
    assert np.abs((loaded.features * index.features).sum(axis=1) - 1).max() < 2e-3   # int8 storage: cosine ~1
    query = features[[7, 3]] * 5.0                                                   # scale does not matter
    nearest = loaded.nearest(query, k=3)
    assert [row[0].caption for row in nearest] == ["caption 7", "caption 3"]
    assert nearest[0][0].similarity > 0.99 and nearest[0][0].similarity >= nearest[0][1].similarity
    with pytest.raises(BundleError, match=r"index\.npz: features \(50, 16\) for 50 captions, expected \[50, 32\]"):
        CaptionIndex.load(tmp_path / "index.npz", dim=32)


def test_threshold_choice_and_rates():
    from t2m.export.writing.index_captions import choose_threshold, rates

    known, unknown = np.array([0.9, 0.8, 0.75, 0.6]), np.array([0.5, 0.55, 0.7])
    threshold = choose_threshold(known, unknown)
    assert 0.7 < threshold < 0.75                                   # one false warning (0.6) beats missing 0.7
    result = rates(known, unknown, threshold)
    assert (result.false_warnings, result.missed_warnings) == (1, 0)
    assert result.false_warning_rate == 0.25 and result.missed_warning_rate == 0.0


@pytest.fixture(scope="module")
def default_engine(default_model):
    from t2m.runtime.engine import OnnxEngine

    return OnnxEngine.load(default_model, intra_op_threads=1)


def test_default_model_warns_about_actions_it_never_saw(default_engine):
    motion = default_engine.generate(_request("a person walks forward", "a person jumps up and down",
                                              "a man sits down on a chair"))
    assert len(motion.warnings) == 2, motion.warnings
    assert motion.warnings[0].startswith("segments.1.text: 'a person jumps up and down' is far from everything")
    assert motion.warnings[1].startswith("segments.2.text: 'a man sits down on a chair'")
    assert "nearest: '" in motion.warnings[0]
    assert default_engine.generate(_request("someone waves with the left hand", "a person bows")).warnings == []


def test_reject_mode_refuses_with_the_segment_named(default_model):
    from t2m.runtime.engine import OnnxEngine

    engine = OnnxEngine.load(default_model, intra_op_threads=1, unknown_text="reject")
    with pytest.raises(RequestLimitError, match=r"^segments\.1\.text: 'someone climbs up a ladder'"):
        engine.generate(_request("a person walks forward", "someone climbs up a ladder"))
    assert len(engine.generate(_request("a person runs")).joints) == 40


def test_shipped_threshold_reproduces_the_recorded_rates(default_model, default_engine):
    """The card's false/missed warning counts, recomputed from the shipped index and the phrasings file."""
    from t2m.export.writing.index_captions import DEFAULT_PHRASINGS

    manifest = json.loads((default_model / "manifest.json").read_text())
    recorded = manifest["caption_index"]["calibration"]
    sets = json.loads(DEFAULT_PHRASINGS.read_text())
    for name in ("calibration", "evaluation"):
        counts = {}
        for kind in ("known", "unknown"):
            texts = sets[name][kind]
            warned = [bool(w) for w in (default_engine.unknown_text_warnings([t], default_engine.text.encode([t]))
                                        for t in texts)]
            counts[kind] = (len(texts), sum(warned) if kind == "known" else len(texts) - sum(warned))
        assert recorded[name] == {"known": counts["known"][0], "unknown": counts["unknown"][0],
                                  "false_warnings": counts["known"][1], "missed_warnings": counts["unknown"][1]}
    assert recorded["evaluation"]["false_warnings"] <= 3 and recorded["evaluation"]["missed_warnings"] <= 3


def test_api_answers_200_with_the_warning_or_422_when_asked(default_model):
    from fastapi.testclient import TestClient

    from t2m.service.app import create_app
    from t2m.service.settings import Settings

    body = {"segments": [{"text": "a person walks forward", "duration": 2.0},
                         {"text": "a baby crawls on the floor", "duration": 2.0}], "seed": 1}
    with TestClient(create_app(Settings(bundle_path=default_model))) as client:
        _wait(client)
        answer = client.post("/generate", json=body)
        assert answer.status_code == 200
        assert answer.json()["warnings"][0].startswith("segments.1.text: 'a baby crawls on the floor'")
        assert "segments.1.text" in answer.headers["X-T2M-Warnings"]
        health = client.get("/health").json()["model"]["extra"]["unknown_text"]
        assert health["detection"] == "warn" and health["captions"] > 10000
    with TestClient(create_app(Settings(bundle_path=default_model, unknown_text="reject"))) as client:
        _wait(client)
        answer = client.post("/generate", json=body)
        assert answer.status_code == 422
        assert answer.json()["detail"][0]["loc"] == ["body", "segments", 1, "text"]


def test_bundle_without_index_says_so(random_bundle):
    from t2m.runtime.engine import OnnxEngine

    engine = OnnxEngine.load(random_bundle, intra_op_threads=1)
    assert engine.limits.details["unknown_text"]["detection"] == "off"
    assert "no index of its training captions" in engine.limits.details["unknown_text"]["reason"]
    assert engine.generate(_request("a person jumps up and down")).warnings == []


def test_index_captions_command_writes_a_verified_indexed_bundle(random_bundle, tmp_path, capsys):
    from t2m.cli.main import main
    from t2m.export.writing.verify import verify_bundle
    from t2m.runtime.engine import OnnxEngine
    from tests.model.synthetic_motion_data import make_dataset

    bundle = tmp_path / "bundle"
    shutil.copytree(random_bundle, bundle)
    data = make_dataset(tmp_path / "data")
    phrasings = _tiny_phrasings(tmp_path)
    assert main(["index-captions", str(bundle), "--data", str(data), "--phrasings", str(phrasings)]) == 0
    assert "threshold" in capsys.readouterr().out
    manifest = verify_bundle(bundle)
    assert manifest["caption_index"]["count"] >= 1 and "caption_index.npz" in manifest["files"]
    assert "## Unknown sentences" in (bundle / "MODEL_CARD.md").read_text()
    engine = OnnxEngine.load(bundle, intra_op_threads=1)
    assert engine.limits.details["unknown_text"]["detection"] == "warn"
    assert main(["index-captions", str(bundle), "--data", str(tmp_path / "nowhere")]) == 2
    assert "no texts/ directory" in capsys.readouterr().err


def _wait(client) -> None:
    import time

    for _ in range(200):
        if client.get("/health").status_code == 200:
            return
        time.sleep(0.05)
    raise AssertionError("the service did not become ready")


def test_a_token_state_bundle_indexes_its_captions_as_its_requests_pool_them(tmp_path, capsys):
    """A DiP bundle's text graph gives token states: the index holds each caption's real tokens averaged, the very
    feature its requests are checked with, so a training caption is found at similarity ~1 and warns of nothing."""
    from t2m.cli.main import main
    from t2m.export.writing.index_captions import encode_with_bundle, training_captions
    from t2m.families.diffusion.random_bundle import build_random_diffusion_bundle
    from t2m.runtime.engine import OnnxEngine
    from t2m.runtime.text import encode_token_states, pooled_token_states
    from tests.model.synthetic_motion_data import make_dataset

    bundle = tmp_path / "dip"
    build_random_diffusion_bundle(bundle, arch="dip", seed=1)
    data = make_dataset(tmp_path / "data")
    phrasings = _tiny_phrasings(tmp_path)
    assert main(["index-captions", str(bundle), "--data", str(data), "--phrasings", str(phrasings)]) == 0
    capsys.readouterr()
    engine = OnnxEngine.load(bundle, intra_op_threads=1)
    assert engine.limits.details["unknown_text"]["detection"] == "warn"
    captions = training_captions(data)
    pooled = pooled_token_states(encode_token_states(engine.text, captions[:3])[0])
    np.testing.assert_allclose(encode_with_bundle(bundle, captions[:3], progress=False), pooled, atol=1e-6)
    nearest = engine.caption_index.nearest(pooled, k=1)
    assert [row[0].caption for row in nearest] == captions[:3] and min(r[0].similarity for r in nearest) > 0.99
    assert engine.generate(GenerationRequest([SegmentRequest(captions[0], 2.0)], seed=0, guidance=1.0)).warnings == []
