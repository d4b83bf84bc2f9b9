"""The text-to-motion metrics of Guo et al. (2022), as reported by T2M-GPT, T2M-HiFiGPT, T2LM and MoGenTS.

Everything here works on embeddings (from an evaluator) or joint positions, as plain numpy arrays, so the
numbers can be recomputed without torch. Conventions follow Guo et al.'s protocol: Euclidean distances in the
evaluator's space, 32-way R-precision, 300 pairs for Diversity, 10 pairs per text for MModality, and a 95%
confidence interval of 1.96 * std / sqrt(repeats) over repeated evaluations.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import linalg


def _as_matrix(name: str, values: np.ndarray) -> np.ndarray:
    array = np.asarray(values, dtype=np.float64)
    if array.ndim != 2:
        raise ValueError(f"{name} must be a [N, D] matrix, got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} contains NaN or infinite values")
    return array


def _check_pairs(text_emb: np.ndarray, motion_emb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    text = _as_matrix("text_emb", text_emb)
    motion = _as_matrix("motion_emb", motion_emb)
    if text.shape != motion.shape:
        raise ValueError(f"text_emb {text.shape} and motion_emb {motion.shape} must have the same shape "
                         "(one row per pair)")
    return text, motion


def activation_statistics(feats: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean [D] and covariance [D, D] of a set of embeddings, the Gaussian that FID compares."""
    feats = _as_matrix("feats", feats)
    if feats.shape[0] < 2:
        raise ValueError(f"need at least 2 embeddings for a covariance, got {feats.shape[0]}")
    return feats.mean(0), np.cov(feats, rowvar=False)


def frechet_distance(mu1: np.ndarray, sigma1: np.ndarray, mu2: np.ndarray, sigma2: np.ndarray,
                     eps: float = 1e-6) -> float:
    """Fréchet distance between N(mu1, sigma1) and N(mu2, sigma2):
    |mu1 - mu2|^2 + tr(sigma1 + sigma2 - 2 (sigma1 sigma2)^(1/2))."""
    mu1, mu2 = np.atleast_1d(np.asarray(mu1, np.float64)), np.atleast_1d(np.asarray(mu2, np.float64))
    sigma1, sigma2 = np.atleast_2d(np.asarray(sigma1, np.float64)), np.atleast_2d(np.asarray(sigma2, np.float64))
    if mu1.shape != mu2.shape or sigma1.shape != sigma2.shape or sigma1.shape != (mu1.size, mu1.size):
        raise ValueError(f"mismatched Gaussian shapes: mu {mu1.shape}/{mu2.shape}, sigma {sigma1.shape}/{sigma2.shape}")
    diff = mu1 - mu2
    covmean, _ = linalg.sqrtm(sigma1 @ sigma2, disp=False)
    if not np.all(np.isfinite(covmean)):
        # Singular product (e.g. fewer samples than dimensions): regularise both covariances slightly.
        offset = np.eye(sigma1.shape[0]) * eps
        covmean = linalg.sqrtm((sigma1 + offset) @ (sigma2 + offset))
    if np.iscomplexobj(covmean):
        # Tiny imaginary parts are numerical noise of sqrtm; large ones mean the input was not a covariance.
        if not np.allclose(np.diagonal(covmean).imag, 0.0, atol=1e-3 * max(1.0, np.abs(covmean).max())):
            raise ValueError(f"sqrtm returned a large imaginary component {np.abs(covmean.imag).max():.3g}")
        covmean = covmean.real
    value = float(diff @ diff + np.trace(sigma1) + np.trace(sigma2) - 2.0 * np.trace(covmean))
    return max(value, 0.0)


def fid(feats_a: np.ndarray, feats_b: np.ndarray) -> float:
    """FID between two sets of evaluator embeddings [N, D] and [M, D]."""
    return frechet_distance(*activation_statistics(feats_a), *activation_statistics(feats_b))


def diversity(feats: np.ndarray, n_pairs: int = 300, seed: int | None = 0) -> float:
    """Mean distance between n_pairs random pairs of embeddings (Guo et al.: 300 pairs).

    With fewer than n_pairs embeddings (quick runs) every embedding is used once per side instead."""
    feats = _as_matrix("feats", feats)
    count = feats.shape[0]
    if count < 2:
        raise ValueError(f"diversity needs at least 2 embeddings, got {count}")
    n_pairs = min(n_pairs, count)
    rng = np.random.default_rng(seed)
    first = rng.choice(count, n_pairs, replace=False)
    second = rng.choice(count, n_pairs, replace=False)
    return float(np.linalg.norm(feats[first] - feats[second], axis=1).mean())


def multimodality(feats_grouped: np.ndarray, n_pairs: int = 10, seed: int | None = 0) -> float:
    """Mean distance between pairs of motions generated from the same text; feats_grouped is [N texts, R repeats, D].

    Guo et al. use 10 pairs per text among the repeats; fewer repeats than n_pairs use every repeat once per side."""
    grouped = np.asarray(feats_grouped, dtype=np.float64)
    if grouped.ndim != 3:
        raise ValueError(f"feats_grouped must be [N, R, D], got shape {grouped.shape}")
    repeats = grouped.shape[1]
    if repeats < 2:
        raise ValueError(f"multimodality needs at least 2 repeats per text, got {repeats}")
    n_pairs = min(n_pairs, repeats)
    rng = np.random.default_rng(seed)
    first = rng.choice(repeats, n_pairs, replace=False)
    second = rng.choice(repeats, n_pairs, replace=False)
    return float(np.linalg.norm(grouped[:, first] - grouped[:, second], axis=2).mean())


def r_precision(text_emb: np.ndarray, motion_emb: np.ndarray, top_k: int = 3, pool: int = 32,
                seed: int | None = 0) -> np.ndarray:
    """Top-1..top_k retrieval accuracy [top_k]: for each text, its own motion is ranked by distance among itself
    and pool - 1 motions drawn at random from the other pairs (Guo et al.'s 32-way R-precision).

    A pair counts as retrieved at k if fewer than k of the distractors are strictly closer to the text. With fewer
    than pool pairs (quick runs) all other pairs are the distractors."""
    text, motion = _check_pairs(text_emb, motion_emb)
    count = text.shape[0]
    if count < 2:
        raise ValueError(f"R-precision needs at least 2 pairs, got {count}")
    distractors = min(pool, count) - 1
    rng = np.random.default_rng(seed)
    # Draw distractor indices from the other count - 1 pairs: sample in [0, count-1) and skip the pair itself.
    others = np.stack([rng.choice(count - 1, distractors, replace=False) for _ in range(count)])
    others = others + (others >= np.arange(count)[:, None])
    true_distance = np.linalg.norm(text - motion, axis=1)
    distractor_distance = np.linalg.norm(text[:, None, :] - motion[others], axis=2)
    rank = (distractor_distance < true_distance[:, None]).sum(1)
    return np.array([(rank < k).mean() for k in range(1, top_k + 1)], dtype=np.float64)


def matching_score(text_emb: np.ndarray, motion_emb: np.ndarray) -> float:
    """MM-Dist: mean distance between each text embedding and its own motion's embedding."""
    text, motion = _check_pairs(text_emb, motion_emb)
    return float(np.linalg.norm(text - motion, axis=1).mean())


def mpjpe(joints_a: np.ndarray, joints_b: np.ndarray) -> float:
    """Mean per-joint position error in the inputs' unit (metres here): mean over frames and joints of the
    Euclidean distance between corresponding joints. Shapes [..., J, 3] must match."""
    a = np.asarray(joints_a, dtype=np.float64)
    b = np.asarray(joints_b, dtype=np.float64)
    if a.shape != b.shape or a.ndim < 2 or a.shape[-1] != 3:
        raise ValueError(f"joints must have matching shapes [..., J, 3], got {a.shape} and {b.shape}")
    return float(np.linalg.norm(a - b, axis=-1).mean())


def mean_confidence_interval(values: Sequence[float] | np.ndarray) -> tuple[float, float]:
    """(mean, half-width of the 95% interval) over repeated evaluations: 1.96 * std / sqrt(n), as the papers report."""
    values = np.asarray(values, dtype=np.float64).ravel()
    if values.size == 0:
        raise ValueError("no values to summarise")
    return float(values.mean()), float(1.96 * values.std() / np.sqrt(values.size))
