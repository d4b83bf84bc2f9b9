"""onnxruntime vs PyTorch, float32: does the bundle compute what the trained modules compute? The checks every
family shares (a family's own step graphs are checked in its folder, e.g. t2m/families/gpt/parity.py):

- Decoder graph: features for random codes vs ``vq.decode(codes) * std + mean`` (residual: some depths -1).
- Text graph: features for captions tokenized with the bundle's tokenizer.json vs the PyTorch encoder.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from t2m.model.networks.vqvae import MotionVQVAE

PARITY_TEXTS = [
    "a person walks forward and then turns around",
    "someone jumps up and down twice",
    "a man waves with his right hand while standing still",
    "the person sits down slowly on a chair and stands up again",
    "run!",
]


@dataclass
class TensorParity:
    shape: tuple[int, ...]
    max_abs_diff: float


@torch.no_grad()
def decoder_parity(vq: MotionVQVAE, mean: np.ndarray, std: np.ndarray, onnx_path: str | Path, batch: int = 2,
                   tokens: int = 12, seed: int = 0) -> TensorParity:
    """decoder.onnx vs vq.decode(codes) * std + mean on random codes (residual: the first motion with unused
    depths)."""
    from t2m.export.graphs.export import ort_session

    generator = torch.Generator().manual_seed(seed)
    residual = vq.config.quantizer == "residual"
    shape = (batch, tokens, vq.config.residual_layers) if residual else (batch, tokens)
    codes = torch.randint(0, vq.config.nb_code, shape, generator=generator)
    if residual and vq.config.residual_layers > 1:
        codes[0, :, 1:] = -1  # the first motion with its first depth only: -1 = unused, a zero vector
    expected = (vq.eval().decode(codes) * torch.from_numpy(np.asarray(std, np.float32))
                + torch.from_numpy(np.asarray(mean, np.float32))).numpy()
    (actual,) = ort_session(onnx_path).run(None, {"codes": codes.numpy()})
    if actual.shape != expected.shape:
        raise ValueError(f"decoder.onnx returned {list(actual.shape)}, PyTorch {list(expected.shape)}")
    return TensorParity(tuple(actual.shape), float(np.abs(actual - expected).max()))


def text_parity(encoder: Any, onnx_path: str | Path, tokenizer_path: str | Path,
                texts: Sequence[str] = PARITY_TEXTS) -> TensorParity:
    """text_encoder.onnx on the bundle's tokenization vs ``encoder.encode(texts)`` (training's features)."""
    from t2m.export.graphs.export import ort_session
    from t2m.export.graphs.text import tokenize

    ids, mask = tokenize(tokenizer_path, list(texts))
    (actual,) = ort_session(onnx_path).run(None, {"input_ids": ids.numpy(), "attention_mask": mask.numpy()})
    expected = encoder.encode(list(texts))
    return TensorParity(tuple(actual.shape), float(np.abs(actual - expected).max()))


