"""The decoding loops' steps over onnxruntime: gpt_step.onnx for the GPT loop (t2m.families.gpt.loop.GptStep), the
masked
family's masked.onnx and residual.onnx for its loop (t2m.families.masked.loop), T2M-HiFiGPT's temporal_step.onnx and
residual_step.onnx for its loop (t2m.families.hifigpt.loop)."""
from __future__ import annotations

from typing import Any

import numpy as np
import onnxruntime as ort

__all__ = ["OnnxGptStep", "OnnxMaskedStep", "OnnxResidualGptStep", "OnnxResidualStep", "OnnxTemporalStep"]


class KvCached:
    """A step graph's key/value cache layout: [n_layer, 2, B, n_head, P, head_dim], empty (P = 0) at the start."""

    def __init__(self, n_layer: int, n_head: int, head_dim: int) -> None:
        self.n_layer, self.n_head, self.head_dim = n_layer, n_head, head_dim

    def empty_cache(self, batch: int) -> np.ndarray:
        return np.zeros((self.n_layer, 2, batch, self.n_head, 0, self.head_dim), dtype=np.float32)

    def keep_rows(self, past: Any, keep: np.ndarray) -> Any:
        """The cache of the rows still stepping (batch axis 2); engine/bound_step.py keeps it on the device."""
        return past[:, :, keep]


class OnnxGptStep(KvCached):
    """One call of gpt_step.onnx: (cond, token, position, length, past_kv) -> (logits, present_kv)."""

    def __init__(self, session: ort.InferenceSession, n_layer: int, n_head: int, head_dim: int,
                 has_length_input: bool) -> None:
        super().__init__(n_layer, n_head, head_dim)
        self.session = session
        self.has_length_input = has_length_input

    def feeds(self, cond: np.ndarray, token: np.ndarray, position: int, length: np.ndarray) -> dict[str, np.ndarray]:
        """Every input but the cache."""
        feeds = {"cond": cond, "token": token, "position": np.asarray([position], dtype=np.int64)}
        if self.has_length_input:
            feeds["length"] = length
        return feeds

    def __call__(self, cond: np.ndarray, token: np.ndarray, position: int, length: np.ndarray,
                 past: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        logits, present = self.session.run(["logits", "present_kv"],
                                           {**self.feeds(cond, token, position, length), "past_kv": past})
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
    see t2m.families.masked.loop.ResidualStep)."""

    def __init__(self, session: ort.InferenceSession, layers: int, pad_id: int, mask_id: int | None = None) -> None:
        self.session, self.layers, self.pad_id, self.mask_id = session, layers, pad_id, mask_id

    def __call__(self, codes: np.ndarray, layer: np.ndarray, cond: np.ndarray, length: np.ndarray) -> np.ndarray:
        (logits,) = self.session.run(["logits"], {"codes": codes, "layer": layer, "cond": cond, "length": length})
        return logits


class OnnxTemporalStep(KvCached):
    """temporal_step.onnx (T2M-HiFiGPT): (cond, codes [B, R], position, length, past_kv) -> (context, stop_logit,
    present_kv)."""

    def __init__(self, session: ort.InferenceSession, depth: int, n_layer: int, n_head: int, head_dim: int,
                 has_length_input: bool) -> None:
        super().__init__(n_layer, n_head, head_dim)
        self.session, self.depth = session, depth
        self.has_length_input = has_length_input

    def feeds(self, cond: np.ndarray, codes: np.ndarray, position: int, length: np.ndarray) -> dict[str, np.ndarray]:
        """Every input but the cache."""
        feeds = {"cond": cond, "codes": codes, "position": np.asarray([position], dtype=np.int64)}
        if self.has_length_input:
            feeds["length"] = length
        return feeds

    def __call__(self, cond: np.ndarray, codes: np.ndarray, position: int, length: np.ndarray,
                 past: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        context, stop, present = self.session.run(["context", "stop_logit", "present_kv"],
                                                  {**self.feeds(cond, codes, position, length), "past_kv": past})
        return context, stop, present


class OnnxResidualGptStep(KvCached):
    """residual_step.onnx (T2M-HiFiGPT): (context [B, E], code [B], depth, past_kv) -> (logits [B, K], present_kv)."""

    def __init__(self, session: ort.InferenceSession, n_layer: int, n_head: int, head_dim: int) -> None:
        super().__init__(n_layer, n_head, head_dim)
        self.session = session

    @staticmethod
    def feeds(context: np.ndarray, code: np.ndarray, depth: int) -> dict[str, np.ndarray]:
        """Every input but the cache."""
        return {"context": context, "code": code, "depth": np.asarray([depth], dtype=np.int64)}

    def __call__(self, context: np.ndarray, code: np.ndarray, depth: int,
                 past: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        logits, present = self.session.run(["logits", "present_kv"],
                                           {**self.feeds(context, code, depth), "past_kv": past})
        return logits, present
