"""What `t2m eval` needs from a model family: codes for these texts and lengths.

Everything else of the evaluation (crops, repeats, metrics, the report) is the same for every family, and decoding
is the VQ's own `decode` (a 1D VQ takes [T] or [T, R] codes, the joint VQ [T, C, R] maps), so a family is only its
generation step. Keeping it this small is what lets the GPT and the masked family be compared on exactly the same
draws and the same evaluator.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol, runtime_checkable

import numpy as np


class CodeFamily(Protocol):
    """A generator of VQ codes for text features: the GPT (t2m.families.gpt.evaluation) or the masked family
    (t2m.families.masked.evaluation)."""

    name: str                      # its model family's name (t2m.bundle.family)
    text_encoder: str              # the text features it is conditioned on ("minilm", "clip")
    max_tokens: int                # longest motion it generates, in tokens (4 frames each)
    paths: dict[str, str]          # its runs by role, in report order
    labels: dict[str, str]         # how the report names each of its runs
    settings: dict[str, Any]       # decoding settings beyond temperature/top-k/guidance, for the report
    batch_by_length: bool          # batch rows of similar lengths together (every step runs at the batch's longest)
    joined: str                    # how a stream's sentences are joined before the one decode, for the report

    def report_note(self) -> str:
        """A sentence on its decoding settings for the report's Models line ("" if there is nothing to say)."""
        ...

    def codes(self, cond: np.ndarray, tokens: Sequence[int], guidance: float, temperature: float,
              top_k: int | None, rng: np.random.Generator) -> list[Any]:
        """One code sequence/map per row of cond [B, Dt], of exactly tokens[i] time steps, in the VQ's layout."""
        ...

    def estimate_tokens(self, cond: np.ndarray, rng: np.random.Generator) -> list[int] | None:
        """Token counts the family would choose itself for these texts (a length estimator), or None."""
        ...


@runtime_checkable
class StreamFamily(Protocol):
    """A family that samples a stream of sentences itself (the diffusion family: DiP's chained calls, MDM's
    in-betweened joins) instead of per-sentence codes concatenated: the stream table then measures its own joins."""

    def sample_streams(self, conds: Sequence[np.ndarray], tokens: Sequence[Sequence[int]], guidance: float,
                       rng: np.random.Generator) -> list[list[Any]]:
        """Per stream (its sentences' condition rows and lengths), each segment's codes of exactly its length."""
        ...


class CodeDecoder(Protocol):
    """Codes -> raw motion features without a VQ module: a served bundle's decoder.onnx (t2m.export.evaluation).
    An evaluation decoding through one has no VQ encoder, so it has no VQ-reconstruction row."""

    frames_per_token: int

    def decode_batch(self, codes: np.ndarray) -> np.ndarray:
        """int64 codes [B, T] (or the family's layout per row) -> de-normalised float32 features [B, frames, D]."""
        ...


class TextFeatureSource(Protocol):
    """A family's own text encoder (a bundle's text_encoder.onnx): captions -> the features it is conditioned on."""

    def encode(self, texts: Sequence[str]) -> np.ndarray: ...
