"""The contrastive evaluator: masking, padding invariance, the loss, learning, checkpoints."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from t2m.model.networks.evaluator import (
    EvaluatorConfig,
    MotionEvaluator,
    embed_motions,
    false_negative_mask,
    info_nce,
    pad_batch,
)

TINY = {"width": 32, "n_layer": 1, "n_head": 2, "embed_dim": 16, "dropout": 0.0}


@pytest.fixture(autouse=True)
def one_thread():
    torch.set_num_threads(1)
    torch.manual_seed(0)


def test_embeddings_are_unit_vectors_and_ignore_padding():
    model = MotionEvaluator(EvaluatorConfig(**TINY)).eval()
    rng = np.random.default_rng(0)
    motions = [rng.normal(size=(n, 263)).astype(np.float32) for n in (21, 64, 100)]
    alone = np.concatenate([embed_motions(model, [m]) for m in motions])
    batched = embed_motions(model, motions)
    np.testing.assert_allclose(alone, batched, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(batched, axis=1), 1.0, atol=1e-5)
    # Garbage in the padded frames changes nothing.
    features, lengths = pad_batch(motions)
    padding = torch.arange(features.shape[1])[None, :, None] >= lengths[:, None, None]
    noisy = features + torch.randn_like(features) * padding
    with torch.no_grad():
        np.testing.assert_allclose(model.encode_motion(noisy, lengths).numpy(), batched, atol=1e-5)


def test_too_long_or_misshaped_motions_are_refused():
    model = MotionEvaluator(EvaluatorConfig(**TINY))
    with pytest.raises(ValueError, match="longer than the evaluator's maximum"):
        model.encode_motion(torch.zeros(1, 200, 263), torch.tensor([200]))
    with pytest.raises(ValueError, match=r"\[B, T, 263\]"):
        model.encode_motion(torch.zeros(1, 20, 251), torch.tensor([20]))
    with pytest.raises(ValueError, match="mean/std"):
        model.set_normalization(np.zeros(5), np.ones(5))


def test_false_negatives_are_identical_captions_only():
    text = torch.tensor([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    mask = false_negative_mask(text, threshold=0.95)
    assert mask.tolist() == [[False, True, False], [True, False, False], [False, False, False]]
    # Two pairs with the same caption: masking the other one removes it from the denominator.
    emb = torch.nn.functional.normalize(torch.tensor([[1.0, 0.0], [1.0, 0.01], [0.0, 1.0]]), dim=1)
    assert info_nce(emb, emb, 0.1, mask) < info_nce(emb, emb, 0.1) - 0.3


def test_training_steps_lower_the_infonce_loss():
    # 6 "actions": each a distinct random pattern over time (+ noise) paired with its own "caption" feature.
    rng = np.random.default_rng(0)
    patterns = rng.normal(size=(6, 40, 263)).astype(np.float32)
    captions = rng.normal(size=(6, 384)).astype(np.float32)
    model = MotionEvaluator(EvaluatorConfig(**TINY))

    def batch():
        labels = rng.permutation(6)
        motions = [patterns[k][: rng.integers(24, 41)] + 0.3 * rng.normal(size=(1, 263)).astype(np.float32)
                   for k in labels]
        features, lengths = pad_batch(motions)
        return features, lengths, torch.from_numpy(captions[labels])

    fixed = batch()
    with torch.no_grad():
        before = float(info_nce(*model(*fixed), model.config.temperature))
    for _ in range(30):  # plain gradient descent: torch.optim's first step imports torch._dynamo (slow here)
        text_emb, motion_emb = model(*batch())
        loss = info_nce(text_emb, motion_emb, model.config.temperature)
        model.zero_grad()
        loss.backward()
        with torch.no_grad():
            for parameter in model.parameters():
                parameter -= 0.1 * parameter.grad
    with torch.no_grad():
        after = float(info_nce(*model(*fixed), model.config.temperature))
    assert after < 0.5 * before, (before, after)


def test_checkpoint_round_trip_keeps_weights_and_statistics(tmp_path):
    from t2m.model.training.checkpoint import load_model, save_checkpoint

    model = MotionEvaluator(EvaluatorConfig(**TINY))
    model.set_normalization(np.full(263, 0.5), np.full(263, 2.0))
    save_checkpoint(tmp_path, model, step=3)
    loaded = load_model(tmp_path, expect_kind="evaluator")
    motion = [np.random.default_rng(1).normal(size=(30, 263)).astype(np.float32)]
    np.testing.assert_allclose(embed_motions(loaded, motion, normalized=False),
                               embed_motions(model, motion, normalized=False), atol=1e-6)
    assert torch.equal(loaded.std, torch.full((263,), 2.0))
