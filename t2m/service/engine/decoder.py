"""Codes -> motion features with the bundle's decoder graph (de-normalisation happens inside the graph)."""
from __future__ import annotations

import numpy as np
import onnxruntime as ort

__all__ = ["Decoder"]


class Decoder:
    """Decodes one request's concatenated codes at once, so the motion is continuous across its segments."""

    def __init__(self, session: ort.InferenceSession, feature_dim: int) -> None:
        self.session = session
        self.feature_dim = feature_dim

    def decode(self, codes: np.ndarray) -> np.ndarray:
        """int64 codes [N] (GPT family), [N, R] (HiFiGPT) or maps [N, C, R] (masked family) -> float32
        [N * frames_per_token, feature_dim] features: one batch row, decoded at once."""
        codes = np.asarray(codes, dtype=np.int64)[None]
        (features,) = self.session.run(["features"], {"codes": codes})
        features = np.asarray(features, dtype=np.float32)
        if features.ndim != 3 or features.shape[0] != 1 or features.shape[2] != self.feature_dim:
            raise RuntimeError(f"decoder.onnx returned features of shape {features.shape}, expected "
                               f"[1, frames, {self.feature_dim}]")
        return features[0]
