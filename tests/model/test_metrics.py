"""The metrics on inputs whose answers are known in closed form."""
from __future__ import annotations

import numpy as np
import pytest

from t2m.model.evaluation import metrics


def test_fid_of_identical_sets_is_zero():
    feats = np.random.default_rng(0).normal(size=(500, 8))
    assert metrics.fid(feats, feats) == pytest.approx(0.0, abs=1e-6)


def test_frechet_distance_matches_the_analytic_value_for_diagonal_gaussians():
    mu1, mu2 = np.array([0.0, 1.0, 2.0]), np.array([1.0, 1.0, 0.0])
    var1, var2 = np.array([1.0, 4.0, 9.0]), np.array([4.0, 1.0, 1.0])
    expected = np.sum((mu1 - mu2) ** 2) + np.sum((np.sqrt(var1) - np.sqrt(var2)) ** 2)  # = 5 + 1 + 1 + 4
    assert metrics.frechet_distance(mu1, np.diag(var1), mu2, np.diag(var2)) == pytest.approx(expected, rel=1e-9)


def test_fid_of_a_shifted_gaussian_sample_is_the_squared_shift():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(20000, 4))
    shift = np.array([3.0, 0.0, -1.0, 2.0])
    b = rng.normal(size=(20000, 4)) + shift
    assert metrics.fid(a, b) == pytest.approx(float(shift @ shift), rel=0.03)


def test_fid_handles_fewer_samples_than_dimensions():
    rng = np.random.default_rng(2)
    value = metrics.fid(rng.normal(size=(10, 32)), rng.normal(size=(10, 32)))
    assert np.isfinite(value) and value > 0


def test_perfect_retriever_has_r_precision_one():
    emb = np.random.default_rng(3).normal(size=(200, 16))
    np.testing.assert_allclose(metrics.r_precision(emb, emb.copy(), top_k=3), [1.0, 1.0, 1.0])
    assert metrics.matching_score(emb, emb) == pytest.approx(0.0)


def test_random_retriever_has_r_precision_one_in_32():
    rng = np.random.default_rng(4)
    text, motion = rng.normal(size=(4000, 16)), rng.normal(size=(4000, 16))
    top = metrics.r_precision(text, motion, top_k=3, pool=32, seed=0)
    np.testing.assert_allclose(top, [1 / 32, 2 / 32, 3 / 32], atol=0.012)
    assert np.all(np.diff(top) >= 0)


def test_r_precision_never_uses_the_pair_itself_as_a_distractor():
    # Only 2 pairs, swapped: every text is closer to the other motion, so the true motion ranks second.
    text = np.array([[0.0, 0.0], [10.0, 0.0]])
    motion = np.array([[9.0, 0.0], [1.0, 0.0]])
    np.testing.assert_allclose(metrics.r_precision(text, motion, top_k=2), [0.0, 1.0])


def test_diversity_of_two_antipodal_clusters():
    # Half the points at +e, half at -e: a random pair is at distance 0 or 2, so about 1 on average.
    feats = np.zeros((1000, 3))
    feats[:500, 0], feats[500:, 0] = 1.0, -1.0
    assert metrics.diversity(feats, n_pairs=300, seed=0) == pytest.approx(1.0, abs=0.15)
    assert metrics.diversity(np.ones((50, 3))) == 0.0


def test_multimodality_of_known_groups():
    grouped = np.zeros((5, 10, 2))
    grouped[:, ::2, 0] = 1.0  # each text: half its repeats at (1, 0), half at (0, 0)
    value = metrics.multimodality(grouped, n_pairs=10, seed=0)
    assert 0.0 < value < 1.0
    assert metrics.multimodality(np.ones((5, 10, 2))) == 0.0


def test_mpjpe_of_a_constant_offset():
    joints = np.random.default_rng(6).normal(size=(20, 22, 3))
    assert metrics.mpjpe(joints, joints + np.array([0.03, 0.0, 0.04])) == pytest.approx(0.05)
    with pytest.raises(ValueError, match="matching shapes"):
        metrics.mpjpe(joints, joints[:10])


def test_confidence_interval_is_the_papers_formula():
    mean, half = metrics.mean_confidence_interval([1.0, 2.0, 3.0, 4.0])
    assert mean == 2.5
    assert half == pytest.approx(1.96 * np.std([1, 2, 3, 4]) / 2)


def test_bad_inputs_are_named():
    with pytest.raises(ValueError, match="text_emb"):
        metrics.r_precision(np.zeros((3, 2)), np.zeros((4, 2)))
    with pytest.raises(ValueError, match="NaN"):
        metrics.fid(np.full((3, 2), np.nan), np.zeros((3, 2)))
