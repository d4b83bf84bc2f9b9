"""The SDK's own small types, mirroring the service's API schema (the SDK imports nothing of the service)."""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeAlias

import numpy as np

__all__ = [
    "Append",
    "BodyPart",
    "EditLike",
    "FrameChunk",
    "Health",
    "InBetween",
    "ModelInfo",
    "Motion",
    "Prepend",
    "RawResult",
    "Regenerate",
    "Segment",
    "SegmentSpan",
    "SegmentsLike",
    "Upload",
    "edits_json",
    "to_segments",
    "warnings_of",
]


@dataclass(frozen=True)
class Segment:
    """One sentence; duration in seconds (0.5-10) or None to let the model end it."""

    text: str
    duration: float | None = None

    def to_json(self) -> dict[str, Any]:
        return {"text": self.text, "duration": self.duration}


SegmentsLike: TypeAlias = str | Segment | Sequence[Segment | tuple[str, float | None] | Mapping[str, Any] | str]


def to_segments(segments: SegmentsLike) -> list[Segment]:
    """Accept a sentence, a Segment, or a list of Segments / (text, duration) pairs / dicts / sentences."""
    if isinstance(segments, (str, Segment)):
        segments = [segments]
    result = []
    for item in segments:
        if isinstance(item, Segment):
            result.append(item)
        elif isinstance(item, str):
            result.append(Segment(item))
        elif isinstance(item, Mapping):
            result.append(Segment(str(item["text"]), item.get("duration")))
        else:
            text, duration = item
            result.append(Segment(text, duration))
    return result


@dataclass(frozen=True)
class SegmentSpan:
    """Which frames a sentence produced: frames[start_frame:end_frame] (end exclusive)."""

    text: str
    start_frame: int
    end_frame: int


@dataclass(frozen=True)
class ModelInfo:
    name: str
    version: str


@dataclass
class Motion:
    """A generated motion: frames [T, J, 3] joint positions in metres, Y up, at `fps` frames per second."""

    frames: np.ndarray
    fps: int
    joints: list[str]
    parents: list[int]
    segments: list[SegmentSpan]
    seed: int
    model: ModelInfo
    warnings: list[str] = field(default_factory=list)
    handle: str | None = None      # what `client.edit` takes back (None from a server before 0.x or a diffusion model)
    edited: list[tuple[int, int]] = field(default_factory=list)   # an edit's answer: (segment, seed) sampled

    @property
    def num_frames(self) -> int:
        return int(self.frames.shape[0])

    @property
    def duration(self) -> float:
        """Seconds of motion."""
        return self.num_frames / self.fps

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> Motion:
        frames = np.asarray(data["frames"], dtype=np.float32)
        if frames.size == 0:
            frames = frames.reshape(0, len(data["joints"]), 3)
        return cls(frames=frames, fps=int(data["fps"]), joints=list(data["joints"]), parents=list(data["parents"]),
                   segments=[SegmentSpan(s["text"], int(s["start_frame"]), int(s["end_frame"]))
                             for s in data["segments"]],
                   seed=int(data["seed"]), model=ModelInfo(**data["model"]), warnings=list(data.get("warnings", [])),
                   handle=data.get("handle"),
                   edited=[(int(e["segment"]), int(e["seed"])) for e in data.get("edited", [])])


@dataclass(frozen=True)
class Regenerate:
    """Sample segment `segment` of a motion again: a new text, seed and/or duration (None keeps its own; a seed of
    None is derived from the motion's seed and the index, the same every time)."""

    segment: int
    text: str | None = None
    seed: int | None = None
    duration: float | None = None

    def to_json(self) -> dict[str, Any]:
        body: dict[str, Any] = {"segment": self.segment}
        body.update({key: value for key, value in (("text", self.text), ("seed", self.seed),
                                                   ("duration", self.duration)) if value is not None})
        return body


@dataclass(frozen=True)
class Append:
    """Add segments after the motion (sampled as one request with `seed`; None: derived from the motion's)."""

    segments: SegmentsLike
    seed: int | None = None
    op: str = "append"

    def to_json(self) -> dict[str, Any]:
        return {"op": self.op, "segments": [s.to_json() for s in to_segments(self.segments)], "seed": self.seed}


@dataclass(frozen=True)
class Prepend(Append):
    """Add segments before the motion."""

    op: str = "prepend"


@dataclass(frozen=True)
class InBetween:
    """Fill the join after segment `after` with a new segment (a model whose /health `extra.edits` has in_between:
    the masked family)."""

    after: int
    text: str
    duration: float
    seed: int | None = None

    def to_json(self) -> dict[str, Any]:
        return {"op": "in_between", "after": self.after, "text": self.text, "duration": self.duration,
                "seed": self.seed}


@dataclass(frozen=True)
class BodyPart:
    """Sample some joints of segment `segment` again ("upper_body" / "lower_body"), from `start` to `end` seconds into
    it (None: all of it), keeping the other joints (a model whose /health `extra.edits` has body_part)."""

    segment: int
    part: str
    text: str | None = None
    start: float | None = None
    end: float | None = None
    seed: int | None = None

    def to_json(self) -> dict[str, Any]:
        body: dict[str, Any] = {"op": "body_part", "segment": self.segment, "part": self.part}
        body.update({key: value for key, value in (("text", self.text), ("start", self.start), ("end", self.end),
                                                   ("seed", self.seed)) if value is not None})
        return body


EditLike: TypeAlias = Regenerate | Append | InBetween | BodyPart | Mapping[str, Any]


@dataclass(frozen=True)
class Upload:
    """A motion to edit that the server did not make (POST /edit's `motion`): joints [T, 22, 3] in metres at `fps`,
    or a BVH file's text with the service's skeleton; `segments` (text, frame count) pairs, or None (the server cuts
    it); `seed` what the edits derive theirs from. The model encodes it with its encoder graph (a model without one
    answers ValidationError)."""

    joints: np.ndarray | None = None
    fps: float | None = None
    bvh: str | None = None
    segments: Sequence[tuple[str, int]] | None = None
    seed: int = 0

    @classmethod
    def of_motion(cls, motion: Motion, seed: int = 0) -> Upload:
        """A Motion's frames with its segments (e.g. one of a server without handles, or changed by hand)."""
        spans = [(s.text, s.end_frame - s.start_frame) for s in motion.segments] or None
        return cls(joints=motion.frames, fps=motion.fps, segments=spans, seed=seed)

    def to_json(self) -> dict[str, Any]:
        body: dict[str, Any] = {"seed": self.seed}
        if self.bvh is not None:
            body["bvh"] = self.bvh
        if self.joints is not None:
            body["joints"] = np.asarray(self.joints, dtype=np.float64).round(6).tolist()
        if self.fps is not None:
            body["fps"] = float(self.fps)
        if self.segments is not None:
            body["segments"] = [{"text": text, "frames": int(frames)} for text, frames in self.segments]
        return body


def edits_json(edits: Sequence[EditLike]) -> list[dict[str, Any]]:
    """The `edits` of a POST /edit body: Regenerate / Append / Prepend / InBetween / BodyPart objects or the API's own
    dicts."""
    return [dict(edit) if isinstance(edit, Mapping) else edit.to_json() for edit in edits]


@dataclass(frozen=True)
class FrameChunk:
    """Frames of a streamed motion as they arrive (final: they never change): frames start_frame ..
    start_frame + len(frames) - 1 of the whole motion, [n, J, 3] metres, at `fps` frames per second."""

    start_frame: int
    frames: np.ndarray
    fps: int

    @property
    def start_seconds(self) -> float:
        return self.start_frame / self.fps


@dataclass(frozen=True)
class Health:
    """GET /health: `model` is the default model's facts, `models` every served model's (the default first)."""

    status: str                       # "ok" | "loading" | "error"
    model: dict[str, Any] | None = None
    detail: str | None = None
    service_version: str | None = None
    models: list[dict[str, Any]] = field(default_factory=list)
    default: str | None = None        # the name of the model a request without `model` gets

    @property
    def ready(self) -> bool:
        return self.status == "ok"

    @property
    def model_names(self) -> list[str]:
        """The names `generate(..., model=...)` accepts (a server from before several models: the one model)."""
        if self.models:
            return [str(entry["name"]) for entry in self.models]
        return [str(self.model["name"])] if self.model else []

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> Health:
        """Reads the fields it knows; fields a newer server adds are ignored, so the SDK keeps working."""
        known = {name: data[name] for name in cls.__dataclass_fields__ if name in data}
        return cls(**{**known, "models": list(known.get("models") or [])})


@dataclass(frozen=True)
class RawResult:
    """A generated file as the server sent it (bvh text or glb bytes), with the seed it used."""

    content: bytes
    media_type: str
    seed: int | None
    warnings: list[str]


def warnings_of(header: str | None) -> list[str]:
    return [part.strip() for part in header.split(" | ")] if header else []


