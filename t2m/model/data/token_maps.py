"""Token maps for the masked and residual transformers: (text feature, codes [T, C, R], length) per clip.

Codes come from either VQ, computed once per clip (t2m.model.data.datasets.precompute_codes): a joint VQ gives
[T, C, R]; a 1D residual VQ gives [T, R] and a plain one [T], both seen here as one column ([T, 1, R]). A clip with
more than ``max_tokens`` rows gives a random window of ``max_tokens`` rows each time; shorter ones are padded with
-1 to ``max_tokens`` rows (:func:`trim_rows` then cuts a batch to its longest motion). Each item draws one of the
clip's captions at random.
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch
from torch.utils.data import Dataset

from t2m.model.data.datasets import MotionReader


def as_token_map(codes: np.ndarray) -> np.ndarray:
    """[T] or [T, R] (1D VQ) or [T, C, R] (joint VQ) -> int64 [T, C, R]."""
    codes = np.asarray(codes, dtype=np.int64)
    if codes.ndim == 1:
        return codes[:, None, None]
    if codes.ndim == 2:
        return codes[:, None, :]
    if codes.ndim == 3:
        return codes
    raise ValueError(f"codes must be [T], [T, R] or [T, C, R], got shape {codes.shape}")


class TokenMapDataset(Dataset):
    """{"cond" [Dt], "codes" [max_tokens, C, R] (-1 past the end), "length", "ends"} per clip; "ends" says whether
    the window reaches the clip's last row (a crop of a longer clip does not: its motion goes on)."""

    def __init__(
        self,
        reader: MotionReader,
        codes: Mapping[str, np.ndarray],
        text_features: Mapping[str, np.ndarray],
        max_tokens: int = 50,
    ) -> None:
        self.max_tokens = max_tokens
        self.items: list[tuple[np.ndarray, list[np.ndarray]]] = []
        self.ids: list[str] = []
        self.captions_of = reader.captions   # id -> its sentences (action balancing)
        for clip_id in reader.ids:
            clip_codes = codes.get(clip_id)
            captions = [text_features[c] for c in reader.captions(clip_id) if c in text_features]
            if clip_codes is None or len(clip_codes) == 0 or not captions:
                continue
            self.items.append((as_token_map(clip_codes), captions))
            self.ids.append(clip_id)
        if not self.items:
            raise ValueError("no clip has both codes and a cached caption feature")
        shapes = {item.shape[1:] for item, _ in self.items}
        if len(shapes) != 1:
            raise ValueError(f"clips have different code map shapes (columns, layers): {sorted(shapes)}")
        self.columns, self.layers = shapes.pop()
        self.token_counts = [min(len(c), max_tokens) for c, _ in self.items]  # for length bucketing

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, index: int) -> dict[str, torch.Tensor]:
        clip_codes, captions = self.items[index]
        caption = captions[int(torch.randint(0, len(captions), ()).item())]
        start = 0
        if len(clip_codes) > self.max_tokens:
            start = int(torch.randint(0, len(clip_codes) - self.max_tokens + 1, ()).item())
        window = clip_codes[start : start + self.max_tokens]
        codes = np.full((self.max_tokens, self.columns, self.layers), -1, dtype=np.int64)
        codes[: len(window)] = window
        return {
            "cond": torch.from_numpy(np.asarray(caption, dtype=np.float32)),
            "codes": torch.from_numpy(codes),
            "length": torch.tensor(len(window), dtype=torch.long),
            "ends": torch.tensor(start + len(window) == len(clip_codes)),
        }


def trim_rows(codes: torch.Tensor, length: torch.Tensor) -> torch.Tensor:
    """Cut a batch's code maps [B, T, ...] to its longest motion (the encoder masks the rest as keys anyway)."""
    return codes[:, : max(int(length.max()), 1)]
