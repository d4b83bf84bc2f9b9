"""How far the bundle's decoder looks: the frames of code t are final once the codes up to t + ahead exist.

The decoder is convolutional (dilated 1D convolutions and nearest upsampling in T2M-GPT's VQ decoder), so every
frame depends on a bounded window of codes. The window is measured on the decoder graph itself when the bundle
loads, so no manifest field has to describe the architecture and an imported decoder is measured like our own:
decode random codes, change the middle code (a decoder of [steps, R] code maps: the middle step's whole row), and see
which frames move. Frames outside the window are computed from
identical inputs with the same shapes, so they do not change by a single bit, and the changed frames give the reach.
A ReLU could hide one change, so several backgrounds and replacement codes are tried and the widest reach is kept;
tests/service/test_streaming_engine.py checks the result against the bound computed from the graph's convolutions and
upsamplings.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

__all__ = ["DecoderReach", "probe_reach"]

PROBE_TOKENS = 64          # first probe length; doubled while the change reaches an end of the probe
MAX_PROBE_TOKENS = 1024    # a decoder that looks further than this streams nothing early
BACKGROUNDS = 2
REPLACEMENTS = 3


@dataclass(frozen=True)
class DecoderReach:
    """The codes a frame depends on: the frames of code t depend on codes t - behind .. t + ahead."""

    ahead: int
    behind: int


def _changed_codes(decode: Callable[[np.ndarray], np.ndarray], codes: np.ndarray, features: np.ndarray,
                   position: int, replacement: int, frames_per_token: int) -> tuple[int, int] | None:
    """The first and last code whose frames (of `features`, the decoded `codes`) change when codes[position] becomes
    `replacement` (every depth of it); None when no frame does."""
    changed = codes.copy()
    changed[position] = replacement
    moved = np.flatnonzero((decode(changed) != features).any(axis=1))
    if not moved.size:
        return None
    return int(moved[0]) // frames_per_token, int(moved[-1]) // frames_per_token


def probe_reach(decode: Callable[[np.ndarray], np.ndarray], codebook_size: int, frames_per_token: int, *,
                depth: int | None = None, tokens: int = PROBE_TOKENS,
                max_tokens: int = MAX_PROBE_TOKENS) -> DecoderReach | None:
    """The decoder's reach measured by changing one code (decode: int64 codes [N], or [N, depth] code maps with
    `depth`, -> features [N * fpt, D]); None when it looks further than `max_tokens` / 2 codes either way (no frame is
    final before the last code)."""
    rng = np.random.default_rng(0)
    while tokens <= max_tokens:
        middle = tokens // 2
        ahead = behind = 0
        for _ in range(BACKGROUNDS):
            codes = rng.integers(0, codebook_size, tokens if depth is None else (tokens, depth))
            features = decode(codes)
            first = int(np.ravel(codes[middle])[0])   # a replacement differs at depth 0 at least
            others = [int(code) for code in rng.permutation(codebook_size) if code != first][:REPLACEMENTS]
            for replacement in others:
                span = _changed_codes(decode, codes, features, middle, replacement, frames_per_token)
                if span is not None:
                    ahead, behind = max(ahead, middle - span[0]), max(behind, span[1] - middle)
        if middle - ahead > 0 and middle + behind < tokens - 1:   # the change stayed clear of both ends
            return DecoderReach(ahead=ahead, behind=behind)
        tokens *= 2
    return None
