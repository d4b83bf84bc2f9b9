"""The decoding loops' steps over onnxruntime: gpt_step.onnx for the GPT loop (t2m.decoding.gpt.GptStep), the masked
family's masked.onnx and residual.onnx for its loop (t2m.decoding.masked)."""
from __future__ import annotations

import numpy as np
import onnxruntime as ort

__all__ = ["OnnxGptStep", "OnnxMaskedStep", "OnnxResidualStep"]


class OnnxGptStep:
    """One call of gpt_step.onnx: (cond, token, position, length, past_kv) -> (logits, present_kv)."""

    def __init__(self, session: ort.InferenceSession, n_layer: int, n_head: int, head_dim: int,
                 has_length_input: bool) -> None:
        self.session = session
        self.n_layer, self.n_head, self.head_dim = n_layer, n_head, head_dim
        self.has_length_input = has_length_input

    def empty_cache(self, batch: int) -> np.ndarray:
        return np.zeros((self.n_layer, 2, batch, self.n_head, 0, self.head_dim), dtype=np.float32)

    def __call__(self, cond: np.ndarray, token: np.ndarray, position: int, length: np.ndarray,
                 past: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        feeds = {"cond": cond, "token": token, "position": np.asarray([position], dtype=np.int64), "past_kv": past}
        if self.has_length_input:
            feeds["length"] = length
        logits, present = self.session.run(["logits", "present_kv"], feeds)
        return logits, present


class OnnxMaskedStep:
    """masked.onnx: (tokens [B, T, C], cond [B, Dt], length [B]) -> logits [B, T, C, K]."""

    def __init__(self, session: ort.InferenceSession, columns: int, mask_id: int) -> None:
        self.session, self.columns, self.mask_id = session, columns, mask_id

    def __call__(self, tokens: np.ndarray, cond: np.ndarray, length: np.ndarray) -> np.ndarray:
        (logits,) = self.session.run(["logits"], {"tokens": tokens, "cond": cond, "length": length})
        return logits


class OnnxResidualStep:
    """residual.onnx: (codes [B, T, C, R], layer [B], cond [B, Dt], length [B]) -> logits of layer q (``mask_id``:
    see t2m.decoding.masked.ResidualStep)."""

    def __init__(self, session: ort.InferenceSession, layers: int, pad_id: int, mask_id: int | None = None) -> None:
        self.session, self.layers, self.pad_id, self.mask_id = session, layers, pad_id, mask_id

    def __call__(self, codes: np.ndarray, layer: np.ndarray, cond: np.ndarray, length: np.ndarray) -> np.ndarray:
        (logits,) = self.session.run(["logits"], {"codes": codes, "layer": layer, "cond": cond, "length": length})
        return logits
