"""Torch datasets over a HumanML3D-layout directory (read by ``t2m.model.data.motion_data.MotionDirectory``).

- :class:`VQWindowDataset`: random fixed-length windows of normalised features, for the VQ-VAE.
- :class:`TextMotionDataset`: (text feature of a random caption, code sequence + End + Pad, length)
  for the GPT, from codes computed once with the trained VQ (:func:`precompute_codes`).

A "reader" is anything with ``ids``, ``features(id)`` [T, D], ``captions(id)`` -> list[str],
``mean`` and ``std`` (the MotionDirectory interface).
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import numpy as np
import torch
from torch.utils.data import Dataset, Sampler

if TYPE_CHECKING:
    from t2m.model.networks.vqvae import MotionVQVAE


class MotionReader(Protocol):
    @property
    def ids(self) -> Sequence[str]: ...

    @property
    def mean(self) -> np.ndarray: ...

    @property
    def std(self) -> np.ndarray: ...

    def features(self, clip_id: str) -> np.ndarray: ...

    def captions(self, clip_id: str) -> list[str]: ...


def open_split(root: str | Path, split: str) -> MotionReader:
    """The MotionDirectory of one split (train/val/test)."""
    from t2m.model.data.motion_data import MotionDirectory

    return MotionDirectory(root, split)


def normalized_features(reader: MotionReader, clip_id: str) -> np.ndarray:
    """(features - mean) / std as float32 [T, D]."""
    features = np.asarray(reader.features(clip_id), dtype=np.float32)
    return (features - reader.mean) / reader.std


class VQWindowDataset(Dataset):
    """One random ``window``-frame crop of a clip per item (clips shorter than the window are left out).

    The clips are held in memory once (normalised); the crop offset is drawn from torch's RNG so
    seeded runs repeat. ``fixed_offsets=True`` gives deterministic crops (start, middle, end) for validation.
    """

    def __init__(self, reader: MotionReader, window: int = 64, fixed_offsets: bool = False) -> None:
        self.window = window
        self.fixed_offsets = fixed_offsets
        self.clips: list[np.ndarray] = []
        self.ids: list[str] = []
        self.captions_of = reader.captions   # id -> its sentences (action balancing)
        for clip_id in reader.ids:
            features = normalized_features(reader, clip_id)
            if features.shape[0] >= window:
                self.clips.append(features)
                self.ids.append(clip_id)
        if not self.clips:
            raise ValueError(f"no clip has at least {window} frames (of {len(reader.ids)} clips)")
        self.items = [(i, None) for i in range(len(self.clips))]
        if fixed_offsets:
            self.items = [
                (i, offset)
                for i, clip in enumerate(self.clips)
                for offset in sorted({0, (clip.shape[0] - window) // 2, clip.shape[0] - window})
            ]

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, index: int) -> torch.Tensor:
        clip_index, offset = self.items[index]
        clip = self.clips[clip_index]
        if offset is None:
            offset = int(torch.randint(0, clip.shape[0] - self.window + 1, ()).item())
        return torch.from_numpy(clip[offset : offset + self.window])


@torch.no_grad()
def precompute_codes(vq: MotionVQVAE, reader: MotionReader, batch_frames: int = 4096) -> dict[str, np.ndarray]:
    """Encode every clip of the reader once: id -> int64 codes [T // 4] (or [T // 4, R])."""
    from tqdm import tqdm

    vq.eval()
    codes: dict[str, np.ndarray] = {}
    for clip_id in tqdm(list(reader.ids), desc="encoding clips", unit="clip"):
        features = normalized_features(reader, clip_id)
        if features.shape[0] < vq.frames_per_token:
            continue
        codes[clip_id] = vq.encode(torch.from_numpy(features)[None])[0].numpy().astype(np.int64)
    return codes


def save_codes(path: str | Path, codes: Mapping[str, np.ndarray]) -> None:
    with open(path, "wb") as handle:
        # allow_pickle (the default) is named so that mypy does not match the ** mapping against it
        np.savez(handle, allow_pickle=True, **{f"clip/{k}": v for k, v in codes.items()})


def load_codes(path: str | Path) -> dict[str, np.ndarray]:
    with np.load(path) as stored:
        return {k[len("clip/"):]: stored[k] for k in stored.files if k.startswith("clip/")}


class TextMotionDataset(Dataset):
    """(cond [Dt], tokens [max_tokens + 1], length) per clip; a random caption each time.

    tokens = codes, End, then Pad up to max_tokens + 1. A clip with more than max_tokens codes
    gives a random crop of max_tokens codes and no End (its motion goes on). ``length`` is the
    number of real codes (for length conditioning). Residual codes use their first layer.
    """

    def __init__(
        self,
        reader: MotionReader,
        codes: Mapping[str, np.ndarray],
        text_features: Mapping[str, np.ndarray],
        codebook_size: int,
        max_tokens: int = 50,
    ) -> None:
        self.codebook_size = codebook_size
        self.max_tokens = max_tokens
        self.end_id, self.pad_id = codebook_size, codebook_size + 1
        self.items: list[tuple[np.ndarray, list[np.ndarray]]] = []
        self.ids: list[str] = []
        self.captions_of = reader.captions   # id -> its sentences (action balancing)
        for clip_id in reader.ids:
            clip_codes = codes.get(clip_id)
            captions = [text_features[c] for c in reader.captions(clip_id) if c in text_features]
            if clip_codes is None or len(clip_codes) == 0 or not captions:
                continue
            clip_codes = clip_codes[:, 0] if clip_codes.ndim == 2 else clip_codes
            self.items.append((clip_codes.astype(np.int64), captions))
            self.ids.append(clip_id)
        # tokens each item fills (codes + End, or max_tokens for a cropped clip): for length bucketing
        self.token_counts = [min(len(c) + 1, max_tokens) for c, _ in self.items]
        if not self.items:
            raise ValueError("no clip has both codes and a cached caption feature")

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, index: int) -> dict[str, torch.Tensor]:
        clip_codes, captions = self.items[index]
        caption = captions[int(torch.randint(0, len(captions), ()).item())]
        tokens = np.full(self.max_tokens + 1, self.pad_id, dtype=np.int64)
        if len(clip_codes) > self.max_tokens:
            start = int(torch.randint(0, len(clip_codes) - self.max_tokens + 1, ()).item())
            tokens[: self.max_tokens] = clip_codes[start : start + self.max_tokens]
            length = self.max_tokens
        else:
            length = len(clip_codes)
            tokens[:length] = clip_codes
            tokens[length] = self.end_id
        return {
            "cond": torch.from_numpy(np.asarray(caption, dtype=np.float32)),
            "tokens": torch.from_numpy(tokens),
            "length": torch.tensor(length, dtype=torch.long),
        }


def trim_padding(tokens: torch.Tensor, pad_id: int) -> torch.Tensor:
    """Drop the trailing columns that are Pad in every row.

    In a causal model no position attends to later ones, and Pad targets are ignored by the loss, so the
    loss is unchanged while the cost of the all-Pad tail is saved."""
    used = (tokens != pad_id).any(dim=0).nonzero()
    return tokens[:, : int(used.max()) + 1] if len(used) else tokens[:, :1]


class LengthBucketSampler(Sampler[list[int]]):
    """Random batches of items with similar token counts (pairs with :func:`trim_padding`).

    Each epoch shuffles all items, cuts the order into pools of ``pool_batches`` batches, sorts each pool by
    length and splits it into batches, then shuffles the batches: every item once per epoch, random
    neighbours, and little padding (clips here range from 5 to 50 tokens). With ``weights`` (per-item
    probabilities, e.g. t2m.model.data.balancing.balanced_weights) an epoch is instead as many items drawn with
    replacement by those weights, bucketed the same way."""

    def __init__(self, token_counts: Sequence[int], batch_size: int, pool_batches: int = 32,
                 generator: torch.Generator | None = None,
                 weights: Sequence[float] | np.ndarray | None = None) -> None:
        self.token_counts = np.asarray(token_counts)
        self.batch_size, self.pool_batches, self.generator = batch_size, pool_batches, generator
        if weights is not None and len(weights) != len(self.token_counts):
            raise ValueError(f"weights: {len(weights)} values for {len(self.token_counts)} items")
        self.weights = None if weights is None else torch.as_tensor(np.asarray(weights, dtype=np.float64))

    def __iter__(self):
        count = len(self.token_counts)
        if self.weights is None:
            order = torch.randperm(count, generator=self.generator).numpy()
        else:
            order = torch.multinomial(self.weights, count, replacement=True, generator=self.generator).numpy()
        pool = self.batch_size * self.pool_batches
        batches = []
        for start in range(0, len(order), pool):
            chunk = order[start : start + pool]
            chunk = chunk[np.argsort(self.token_counts[chunk], kind="stable")]
            batches += [chunk[i : i + self.batch_size].tolist() for i in range(0, len(chunk), self.batch_size)]
        for index in torch.randperm(len(batches), generator=self.generator).tolist():
            yield batches[index]

    def __len__(self) -> int:
        return -(-len(self.token_counts) // self.batch_size)
