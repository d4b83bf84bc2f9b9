"""Codes -> motion features with the bundle's decoder graph (de-normalisation happens inside the graph).

The graph has one input; it is fed by its declared name and element type: int64 `codes` for the token families,
float32 `motion` (normalised feature frames, [B, frames, D]) for the diffusion family, whose model makes the
features itself and whose decoder only de-normalises them (t2m/families/diffusion/family.py)."""
from __future__ import annotations

import numpy as np
import onnxruntime as ort

__all__ = ["Decoder"]


class Decoder:
    """Decodes one request's concatenated codes at once, so the motion is continuous across its segments."""

    def __init__(self, session: ort.InferenceSession, feature_dim: int) -> None:
        self.session = session
        self.feature_dim = feature_dim
        (graph_input,) = session.get_inputs()
        self.input_name = graph_input.name
        self.input_dtype = np.float32 if graph_input.type == "tensor(float)" else np.int64

    def decode(self, codes: np.ndarray) -> np.ndarray:
        """int64 codes [N] (GPT family), [N, R] (HiFiGPT), maps [N, C, R] (masked family), or normalised frames
        [N, D] (diffusion family) -> float32 [N * frames_per_token, feature_dim] features: one batch row, decoded at
        once."""
        codes = np.asarray(codes, dtype=self.input_dtype)[None]
        (features,) = self.session.run(["features"], {self.input_name: codes})
        features = np.asarray(features, dtype=np.float32)
        if features.ndim != 3 or features.shape[0] != 1 or features.shape[2] != self.feature_dim:
            raise RuntimeError(f"decoder.onnx returned features of shape {features.shape}, expected "
                               f"[1, frames, {self.feature_dim}]")
        return features[0]
