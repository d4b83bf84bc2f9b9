"""What the engine asks of a family's served decoding object (the `serve` hook of t2m.bundle.family.ModelFamily).

A family's object turns requests into jobs (its own job type: checks the request against the model, encodes the
texts, draws its own seeded generator) and jobs into per-segment codes; the engine does the rest the same way for
every family: text warnings, one decode of the concatenated codes, joints, formats. Families whose capabilities
say `continuous_batching` also start cohorts that step at shared boundaries (t2m.decoding.lockstep.Cohort). An object
whose model can end a segment given no duration says how in an `ends_segments` attribute (a few words, shown by
/health; see `ends_segments` below); without it a client is told that a null duration is refused. An object whose
decoder.onnx reads something other than codes (the diffusion family: normalised frames) measures that decoder's
reach itself and gives it as a `decoder_reach` attribute (engine/reach.py's DecoderReach; see `decoder_reach`). An
object whose codes are tokens says what a step of them is in a `code_layout` attribute (types.CodeLayout: what an
answer's handle carries and checks; see `code_layout`); without it answers carry no handle."""
from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np

from t2m.runtime.text import TextEncoder
from t2m.runtime.types import CodeLayout, GenerationRequest, ModelLimits

__all__ = ["FamilyCodes", "FamilyJob", "code_layout", "decoder_reach", "ends_segments"]


class FamilyJob(Protocol):
    """A request's work for its family's loop; `conds` are its segments' text features (the unknown-text check)."""

    conds: np.ndarray


class FamilyCodes(Protocol):
    """Requests -> per-segment codes in the layout the bundle's decoder.onnx reads."""

    def job(self, request: GenerationRequest, text: TextEncoder, limits: ModelLimits) -> Any:
        """The request as a job of this family's loop; a RequestLimitError names the field it breaks."""
        ...

    def sample(self, jobs: Sequence[Any], max_tokens: int,
               on_step: Callable[[int], None] | None) -> list[list[np.ndarray] | None]:
        """Every job's segments' codes (None: cancelled on the way), all jobs batched together."""
        ...


def ends_segments(codes: object) -> str | None:
    """How the family's served object ends a segment of null duration ("its End token"), None when it cannot: its
    optional `ends_segments` attribute."""
    how = getattr(codes, "ends_segments", None)
    return how if isinstance(how, str) and how else None


def decoder_reach(codes: object) -> Any:
    """The decoder's reach the family's served object measured itself (its optional `decoder_reach` attribute), or
    None: the engine probes the decoder with codes (engine/reach.py)."""
    return getattr(codes, "decoder_reach", None)


def code_layout(codes: object) -> CodeLayout | None:
    """What one step of the family's codes is (its optional `code_layout` attribute), or None: its codes are not
    tokens (the diffusion family's frames) and its answers carry no handle."""
    layout = getattr(codes, "code_layout", None)
    return layout if isinstance(layout, CodeLayout) else None
