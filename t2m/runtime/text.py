"""Sentences -> text features: the bundle's tokenizer (the `tokenizers` library) and its text graph.

All texts of one request go through the graph as one padded batch; pooling and normalisation are inside the graph
(the same as in training), so this module only has to produce input_ids and attention_mask the way training did.
"""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import onnxruntime as ort
from tokenizers import Tokenizer

__all__ = ["TextEncoder", "encode_token_states", "load_tokenizer", "pooled_token_states"]


def load_tokenizer(file: Path, max_length: int) -> Tokenizer:
    """The bundle's tokenizer, truncating to the manifest's max_length and padding a batch to its longest text.

    A tokenizer.json that already configures padding (e.g. CLIP's fixed 77) keeps its own padding.
    """
    try:
        tokenizer = Tokenizer.from_file(str(file))
    except Exception as error:  # tokenizers raises a bare Exception for a malformed file
        from t2m.bundle import BundleError
        raise BundleError(f"{file}: the tokenizers library cannot read it ({error})") from None
    tokenizer.enable_truncation(max_length=max_length)
    if tokenizer.padding is None:
        pad_token = "[PAD]" if tokenizer.token_to_id("[PAD]") is not None else None
        pad_id = tokenizer.token_to_id(pad_token) if pad_token else 0
        tokenizer.enable_padding(pad_id=pad_id, pad_token=pad_token or "[PAD]")
    return tokenizer


class TextEncoder:
    """Encodes a list of sentences into float32 [N, Dt] features with one run of the text graph."""

    def __init__(self, session: ort.InferenceSession, tokenizer: Tokenizer) -> None:
        self.session = session
        self.tokenizer = tokenizer

    def encode(self, texts: Sequence[str]) -> np.ndarray:
        encodings = self.tokenizer.encode_batch(list(texts))
        input_ids = np.asarray([e.ids for e in encodings], dtype=np.int64)
        attention_mask = np.asarray([e.attention_mask for e in encodings], dtype=np.int64)
        (features,) = self.session.run(["text_features"], {"input_ids": input_ids, "attention_mask": attention_mask})
        return np.asarray(features, dtype=np.float32)


def encode_token_states(text: TextEncoder, texts: Sequence[str]) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Each sentence's token states [L_i, Dt] (its own tokens, the batch's padding cut off) and mask [L_i] (all
    True), from the text graph's `token_states` output."""
    encodings = text.tokenizer.encode_batch(list(texts))
    ids = np.asarray([e.ids for e in encodings], dtype=np.int64)
    mask = np.asarray([e.attention_mask for e in encodings], dtype=np.int64)
    (states,) = text.session.run(["token_states"], {"input_ids": ids, "attention_mask": mask})
    counts = mask.sum(axis=1)
    return ([np.asarray(row[:count], np.float32) for row, count in zip(states, counts)],
            [np.ones(int(count), bool) for count in counts])


def pooled_token_states(states: Sequence[np.ndarray]) -> np.ndarray:
    """Each text's real tokens' states averaged: MiniLM's own sentence pooling (before its normalisation), the
    features a token-state bundle's caption index and unknown-text check compare."""
    return np.stack([row.mean(axis=0) for row in states]).astype(np.float32)
