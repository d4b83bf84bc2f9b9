"""gpt_step.onnx as the GPT loop's step (t2m.decoding.gpt.GptStep): the only onnxruntime code of the GPT family."""
from __future__ import annotations

import numpy as np
import onnxruntime as ort

__all__ = ["OnnxGptStep"]


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
