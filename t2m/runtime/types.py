"""Plain data passed between the HTTP layer and the engine (no pydantic, no onnxruntime).

The engine works on resolved requests (seed and guidance already chosen) so that it is deterministic and easy to
call from the CLI, the batcher and tests alike.
"""
from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from t2m.decoding.inpaint import Inpaint
from t2m.motion.constants import FPS, FRAMES_PER_TOKEN

__all__ = [
    "CodeLayout",
    "ComposingEngine",
    "EncodingEngine",
    "Engine",
    "FrameSink",
    "GenerationCancelled",
    "GenerationRequest",
    "ModelLimits",
    "Motion",
    "RecipeEditingEngine",
    "RequestLimitError",
    "SegmentRequest",
    "SegmentSpan",
    "SteppingEngine",
    "frames_for_duration",
    "tokens_for_duration",
]


def tokens_for_duration(duration: float, fps: int = FPS, frames_per_token: int = FRAMES_PER_TOKEN) -> int:
    """Code tokens for a segment of `duration` seconds: round(duration * fps / frames_per_token), at least 1.

    Python's round (half to even) is the documented formula: frames = round(duration * 20 / 4) * 4.
    """
    return max(1, round(duration * fps / frames_per_token))


def frames_for_duration(duration: float, fps: int = FPS) -> int:
    """Frames of a segment of `duration` seconds in the answer: round(duration * fps), at least 1, whatever the
    model's frames_per_token (the engine fits the decoded frames to it: engine/timeline.py). Python's round (half to
    even): 0.525 s -> 10 frames."""
    return max(1, round(duration * fps))


@dataclass(frozen=True)
class CodeLayout:
    """What one code step of a segment is, for the model's decoder: an array of `shape` (() for one code, (R,) for
    a residual row, (C, R) for a joint-token map's row) whose values along its first axis's column c are
    low..bounds[c] - 1 (a single bound holds for every value; `low` -1 where -1 marks an unused residual layer, as
    in the masked family's maps). What an answer's handle carries per step (service/handles.py) and checks coming
    back."""

    shape: tuple[int, ...]
    bounds: tuple[int, ...]
    low: int = 0

    def __post_init__(self) -> None:
        columns = self.shape[0] if self.shape else 1
        if len(self.bounds) not in (1, columns):
            raise ValueError(f"{len(self.bounds)} code bounds for {columns} column(s)")

    @property
    def values(self) -> int:
        """Values per step."""
        return int(np.prod(self.shape, dtype=np.int64)) if self.shape else 1

    def out_of_range(self, codes: np.ndarray) -> np.ndarray:
        """Per step of `codes` [steps, *shape]: whether any value lies outside its column's low..bound - 1."""
        columns = len(self.bounds)
        rows = np.asarray(codes).reshape(len(codes), columns, -1)
        bounds = np.asarray(self.bounds, dtype=np.int64).reshape(1, columns, 1)
        outside = (rows < self.low) | (rows >= bounds)
        return np.asarray(outside.reshape(len(codes), -1).any(axis=1))


@dataclass(frozen=True)
class ModelLimits:
    """What the HTTP layer needs to know about the loaded model to validate and default a request."""

    name: str
    version: str
    fps: int
    frames_per_token: int
    max_tokens: int
    codebook_size: int
    default_guidance: float
    unconditional_branch: bool
    length_conditioning: bool = False
    skeleton: str = "smpl22"
    joint_names: tuple[str, ...] = ()
    parents: tuple[int, ...] = ()
    details: dict = field(default_factory=dict)   # extra facts shown by /health (licence, text encoder, ...)
    ends_segments: str | None = None   # how the model ends a segment of null duration (None: it cannot; a 422)
    codes: CodeLayout | None = None    # its segments' codes as handles carry them (None: not tokens, no handle)
    edits: frozenset[str] = frozenset()   # the edit kinds POST /edit serves for it (its family's capabilities)
    inpaints: bool = False   # its edits fill masked tokens with the kept ones around them (the masked family)
    body_parts: dict[str, tuple[int, ...]] = field(default_factory=dict)   # body_part edits: part -> token columns
    encodes: bool = False    # its bundle has encoder.onnx: POST /edit takes uploaded motions (service/uploads.py)
    recipe: bool = False     # its answers' handles are recipes (service/recipes.py: the diffusion family's frames)

    def guidance(self, requested: float | None = None) -> float:
        """The guidance scale to use: the requested one, else the model's default (1 = off for a model without a
        trained unconditional branch, whatever its manifest says)."""
        if requested is not None:
            return float(requested)
        return float(self.default_guidance if self.unconditional_branch else 1.0)

    @property
    def max_segment_seconds(self) -> float:
        """The length of a free (duration null) segment at most: max_tokens tokens."""
        return self.max_tokens * self.frames_per_token / self.fps

    @property
    def null_duration(self) -> bool:
        """Whether a segment may leave its duration null (the model ends it: a stop rule or a length estimator)."""
        return self.ends_segments is not None


@dataclass(frozen=True)
class SegmentRequest:
    text: str
    duration: float | None   # seconds; None = the model ends the segment with its End token


FrameSink = Callable[[np.ndarray], None]
"""Receives a streamed request's frames (joints float32 [n, J, 3]) in order, from the engine's thread, as they become
final; what it has not received when the Motion is returned, the Motion's joints hold."""


@dataclass
class GenerationRequest:
    """A validated request with every choice made: the same object always gives the same motion."""

    segments: list[SegmentRequest]
    seed: int
    guidance: float = 1.0
    temperature: float = 1.0
    top_k: int | None = None
    cancel_event: threading.Event = field(default_factory=threading.Event, compare=False, repr=False)
    on_frames: FrameSink | None = field(default=None, compare=False, repr=False)   # streaming: early frames go here
    # an edit of a family whose loop inpaints (ModelLimits.inpaints): per segment None or its map with the kept codes
    # around it (t2m.decoding.inpaint); the segment's answer is the map's kept rows
    inpaint: tuple[Inpaint | None, ...] | None = field(default=None, compare=False, repr=False)

    def cancel(self) -> None:
        """Ask the engine to stop working on this request (e.g. its HTTP client timed out)."""
        self.cancel_event.set()

    @property
    def cancelled(self) -> bool:
        return self.cancel_event.is_set()


@dataclass(frozen=True)
class SegmentSpan:
    text: str
    start_frame: int
    end_frame: int   # exclusive: frames[start_frame:end_frame] belong to the segment


@dataclass
class Motion:
    """A generated motion: joint positions in metres (Y up) plus which frames each sentence produced."""

    joints: np.ndarray          # float32 [T, J, 3]
    fps: int
    segments: list[SegmentSpan]
    seed: int
    tokens: int = 0             # code tokens generated (for metrics)
    warnings: list[str] = field(default_factory=list)
    codes: list[np.ndarray] | None = None   # each segment's codes as decoded (what an answer's handle keeps)
    handle: str | None = None   # the answer's handle when it is made with the motion (a diffusion edit's recipe)


class RequestLimitError(ValueError):
    """The request breaks a limit of the loaded model. It carries the request field it is about (`field`, dotted:
    "segments.1.duration", "top_k"), so that the HTTP layer answers a 422 at that field and the CLI names it; its
    text reads "<field>: <why>"."""

    def __init__(self, field: str, why: str) -> None:
        super().__init__(f"{field}: {why}")
        self.field = field
        self.why = why

    @property
    def location(self) -> tuple[str | int, ...]:
        """The field as a validation error's `loc` below the body: ("segments", 1, "duration")."""
        return tuple(int(part) if part.isdigit() else part for part in self.field.split("."))


class GenerationCancelled(RuntimeError):
    """The request was cancelled (timed out) before the engine finished it."""


class Engine(Protocol):
    """What every batcher needs from an engine (OnnxEngine, or a stand-in in tests). The abilities only some engines
    have are the protocols below, checked with isinstance."""

    limits: ModelLimits

    def generate_batch(self, requests: Sequence[GenerationRequest]) -> list[Motion | BaseException]:
        """Generate several requests together; a failure of one request is returned in its place."""
        ...


@runtime_checkable
class SteppingEngine(Engine, Protocol):
    """An engine whose requests can join running work at step boundaries (continuous batching): it prepares requests
    off the stepping thread, runs sessions of cohorts, and finishes each request from its codes."""

    def continuous(self, order: Any = None) -> Any:
        """A running session (t2m.runtime.continuous.RunningCohorts), or None when its family runs batches whole."""
        ...

    def prepare(self, requests: Sequence[GenerationRequest]) -> Any:
        """The requests' jobs (texts encoded, generators seeded), failures in their places."""
        ...

    def finish(self, request: GenerationRequest, segment_codes: list[np.ndarray] | None,
               warnings: list[str]) -> Motion | BaseException:
        """A request's motion from its sampled codes (None: cancelled on the way), or its failure."""
        ...


@runtime_checkable
class EncodingEngine(Protocol):
    """An engine that turns motion features into its codes (a bundle with encoder.onnx): uploads are edited."""

    def encode(self, features: np.ndarray) -> np.ndarray:
        ...


@runtime_checkable
class RecipeEditingEngine(Protocol):
    """An engine whose answers' handles are recipes (the diffusion family): it edits such a handle itself."""

    def edit_recipe(self, handle: str, edits: Sequence[Any]) -> Any:
        ...


@runtime_checkable
class ComposingEngine(Protocol):
    """An engine that decodes codes it is given into a motion (the token families): edits of handles."""

    limits: ModelLimits

    def compose(self, request: GenerationRequest, segment_codes: Sequence[np.ndarray]) -> Motion:
        ...
