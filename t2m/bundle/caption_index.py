"""caption_index.npz: the text features of a model's training captions, so the service can tell a sentence the model
has never seen anything like from one it was trained on.

Stored compactly (features are unit vectors, int8 per row with a float32 scale: cosine error ~1e-3) and read back as
float32 unit vectors. The index holds what the bundle's own text graph computes for each caption, so a request's
feature and the index compare like with like.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from t2m.bundle.errors import BundleError

__all__ = ["CaptionIndex", "Neighbour", "unit_rows"]


def unit_rows(features: np.ndarray) -> np.ndarray:
    """Rows scaled to length 1 (CLIP features are not normalised; cosine similarity needs them to be)."""
    features = np.asarray(features, dtype=np.float32)
    return features / np.maximum(np.linalg.norm(features, axis=1, keepdims=True), 1e-12)


@dataclass(frozen=True)
class Neighbour:
    caption: str
    similarity: float


@dataclass(frozen=True)
class CaptionIndex:
    """Unique training captions and their unit text features [N, D]."""

    captions: tuple[str, ...]
    features: np.ndarray

    @classmethod
    def build(cls, captions: list[str], features: np.ndarray) -> CaptionIndex:
        if len(captions) != len(features) or not captions:
            raise ValueError(f"{len(captions)} captions for {len(features)} feature rows")
        return cls(tuple(captions), unit_rows(features))

    def save(self, path: Path) -> None:
        scale = np.abs(self.features).max(axis=1).clip(1e-12) / 127.0
        quantised = np.round(self.features / scale[:, None]).astype(np.int8)
        with open(path, "wb") as stream:   # np.savez_compressed would append .npz to a str path
            np.savez_compressed(stream, captions=np.asarray(self.captions), features=quantised,
                                scale=scale.astype(np.float32))

    @classmethod
    def load(cls, path: Path, dim: int) -> CaptionIndex:
        """Read and check an index whose features must be `dim` wide (the bundle's text feature size)."""
        try:
            with np.load(path, allow_pickle=False) as data:
                captions, quantised, scale = data["captions"], data["features"], data["scale"]
        except (OSError, ValueError, KeyError) as error:
            raise BundleError(f"{path}: not a caption index (captions, features, scale arrays): {error}") from None
        if quantised.ndim != 2 or quantised.shape[1] != dim or len(captions) != len(quantised) != len(scale):
            raise BundleError(f"{path}: features {quantised.shape} for {len(captions)} captions, expected "
                              f"[{len(captions)}, {dim}]")
        return cls(tuple(str(c) for c in captions), unit_rows(quantised.astype(np.float32) * scale[:, None]))

    def nearest(self, queries: np.ndarray, k: int = 3) -> list[list[Neighbour]]:
        """The k captions most similar (cosine) to each query row, best first."""
        similarity = unit_rows(queries) @ self.features.T                 # [Q, N]
        k = min(k, similarity.shape[1])
        if k == 0:
            return [[] for _ in range(len(similarity))]
        # the k best by a partial sort (every request pays this); ties at the k-th value are all kept as candidates,
        # so the order is exactly a full stable sort's: best first, the lower index first among equals
        kth = np.partition(similarity, -k, axis=1)[:, -k]
        out = []
        for q, row in enumerate(similarity):
            candidates = np.flatnonzero(row >= kth[q])
            best = candidates[np.argsort(-row[candidates], kind="stable")[:k]]
            out.append([Neighbour(self.captions[j], float(row[j])) for j in best])
        return out
