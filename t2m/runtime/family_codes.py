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

from collections.abc import Callable, Mapping, Sequence
from typing import Any, Protocol, runtime_checkable

import numpy as np

from t2m.runtime.text import TextEncoder
from t2m.runtime.types import CodeLayout, GenerationRequest, ModelLimits

__all__ = [
    "BodyParts",
    "EndsSegments",
    "FamilyCodes",
    "FamilyJob",
    "HasCodeLayout",
    "MeasuresDecoderReach",
    "RecipeHandles",
    "StepsOneGraph",
    "body_parts",
    "code_layout",
    "decoder_reach",
    "ends_segments",
    "recipe_handles",
]


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


@runtime_checkable
class EndsSegments(Protocol):
    """A served object whose model can end a segment given no duration, and says how ("its End token")."""

    ends_segments: str


@runtime_checkable
class MeasuresDecoderReach(Protocol):
    """A served object whose decoder.onnx reads something other than codes (the diffusion family's frames), so it
    measures that decoder's reach itself (t2m.runtime.reach.DecoderReach)."""

    decoder_reach: Any


@runtime_checkable
class HasCodeLayout(Protocol):
    """A served object whose codes are tokens: what one step of them is (an answer's handle carries and checks it)."""

    code_layout: CodeLayout


@runtime_checkable
class StepsOneGraph(Protocol):
    """A served object stepping one graph per token (the GPT family's): quantisation parity wraps its step."""

    step: Any


@runtime_checkable
class BodyParts(Protocol):
    """A served object that edits body parts: part name -> the token columns (or channels) it covers."""

    body_parts: Mapping[str, Any]


@runtime_checkable
class RecipeHandles(Protocol):
    """A served object whose answers' handles are recipes, replayed (the diffusion family), not codes: it makes an
    edit of such a handle itself, on its own frames."""

    recipe_handles: bool

    def edit_recipe(self, engine: Any, handle: str, edits: Sequence[Any]) -> Any:
        """The edit of a recipe handle (t2m.runtime.editing.EditResult); HandleError / EditError for a 422."""
        ...


def ends_segments(codes: object) -> str | None:
    """How the family's served object ends a segment of null duration, None when it cannot."""
    return codes.ends_segments if isinstance(codes, EndsSegments) and codes.ends_segments else None


def decoder_reach(codes: object) -> Any:
    """The decoder's reach the family's served object measured itself, or None: the engine probes the decoder with
    codes (t2m/runtime/reach.py)."""
    return codes.decoder_reach if isinstance(codes, MeasuresDecoderReach) else None


def code_layout(codes: object) -> CodeLayout | None:
    """What one step of the family's codes is, or None: its codes are not tokens (the diffusion family's frames)
    and its answers carry no handle."""
    return codes.code_layout if isinstance(codes, HasCodeLayout) and isinstance(codes.code_layout, CodeLayout) \
        else None


def body_parts(codes: object) -> dict[str, Any]:
    """The parts the family's served object can edit, {} when it edits none."""
    return dict(codes.body_parts) if isinstance(codes, BodyParts) else {}


def recipe_handles(codes: object) -> bool:
    """Whether the family's served object answers with recipes (replayed) instead of codes."""
    return isinstance(codes, RecipeHandles) and bool(codes.recipe_handles)
