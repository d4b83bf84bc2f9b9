"""POST /edit's request (a handle or an uploaded motion, and the edits) and its answer."""
from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Discriminator,
    Field,
    StringConstraints,
    Tag,
    model_validator,
)

from t2m.api.answers import MotionResponse
from t2m.api.common import ModelName, OutputFormat, Seed, StrictModel, Text, json_integer
from t2m.api.generate import Segment
from t2m.runtime.limits import (
    MAX_BVH_CHARS,
    MAX_DURATION_S,
    MAX_HANDLE_CHARS,
    MAX_SEGMENTS,
    MAX_UPLOAD_FPS,
    MAX_UPLOAD_FRAMES,
    MIN_DURATION_S,
)


class RegenerateEdit(StrictModel):
    """Sample one segment of the handle's motion again, with a new text, seed and/or duration."""

    op: Literal["regenerate"] = Field("regenerate", description="This kind of edit (the default).")
    segment: Annotated[int, Field(ge=0), BeforeValidator(json_integer)] = Field(
        description="Index of the segment in the handle (0 = the first).", examples=[1])
    text: Text | None = Field(None, description="Its new text; null keeps the segment's own.",
                              examples=["a person raises the left hand"])
    seed: Seed | None = Field(None, description="Its seed; null derives one from the handle's seed and the segment's "
                                                "index (the same on every call: send a seed to re-roll).")
    duration: float | None = Field(None, ge=MIN_DURATION_S, le=MAX_DURATION_S,
                                   description="Its new duration in seconds; null keeps the segment's own.")


class ContinueEdit(StrictModel):
    """Add segments after (append) or before (prepend) the handle's motion; its own segments are kept."""

    op: Literal["append", "prepend"]
    segments: list[Segment] = Field(min_length=1, max_length=MAX_SEGMENTS)
    seed: Seed | None = Field(None, description="The new segments are sampled as one request with this seed (as "
                                                "/generate samples its segments); null derives one from the handle's "
                                                "seed and the op.")


class InBetweenEdit(StrictModel):
    """Fill a gap at the join after segment `after` with a new segment of this text and duration, keeping both
    sides (a family whose loop inpaints: the masked and diffusion families)."""

    op: Literal["in_between"]
    after: Annotated[int, Field(ge=0), BeforeValidator(json_integer)] = Field(
        description="The new segment goes between segment `after` and segment `after + 1` of the handle.",
        examples=[0])
    text: Text = Field(description="What happens in the gap.", examples=["a person turns around"])
    duration: float = Field(ge=MIN_DURATION_S, le=MAX_DURATION_S, description="The gap's length in seconds.")
    seed: Seed | None = Field(None, description="Its seed; null derives one from the handle's seed and `after`.")


class BodyPartEdit(StrictModel):
    """Regenerate some joints of one segment (over all of it, or from `start` to `end` seconds into it), keeping the
    other joints' tokens (a joint-token masked model) or feature channels (a diffusion model: /health `extra.edits`
    lists body_part)."""

    op: Literal["body_part"]
    segment: Annotated[int, Field(ge=0), BeforeValidator(json_integer)] = Field(
        description="Index of the segment in the handle.", examples=[1])
    part: Literal["upper_body", "lower_body"] = Field(description="The joints to regenerate.")
    text: Text | None = Field(None, description="What the part does; null keeps the segment's text.",
                              examples=["a person waves with both hands"])
    start: float | None = Field(None, ge=0.0, le=MAX_DURATION_S,
                                description="Seconds into the segment where the change starts; null: its start.")
    end: float | None = Field(None, gt=0.0, le=MAX_DURATION_S,
                              description="Seconds into the segment where it ends; null: the segment's end.")
    seed: Seed | None = Field(None, description="Its seed; null derives one from the handle's seed and the segment.")


_EDIT_TAGS = {"append": "continue", "prepend": "continue", "in_between": "in_between", "body_part": "body_part"}


def _edit_kind(value: Any) -> str:
    op = value.get("op") if isinstance(value, dict) else getattr(value, "op", None)
    return _EDIT_TAGS.get(op, "regenerate") if isinstance(op, str) else "regenerate"


Edit = Annotated[Annotated[RegenerateEdit, Tag("regenerate")] | Annotated[ContinueEdit, Tag("continue")]
                 | Annotated[InBetweenEdit, Tag("in_between")] | Annotated[BodyPartEdit, Tag("body_part")],
                 Discriminator(_edit_kind)]


class UploadSegment(StrictModel):
    """A stretch of an uploaded motion and what happens in it (the text a regenerate edit keeps)."""

    text: Text = Field(description="What happens in these frames.", examples=["a person walks forward"])
    frames: Annotated[int, Field(ge=1, le=MAX_UPLOAD_FRAMES), BeforeValidator(json_integer)] = Field(
        description="How many of the upload's frames (at its own frame rate) it covers; the segments' frames add up "
                    "to the upload's.")


Joint = Annotated[list[float], Field(min_length=3, max_length=3)]


class UploadedMotion(StrictModel):
    """A motion the user brings instead of a handle: `joints` (the json answer's layout) or `bvh` (a BVH file as
    this service writes them), encoded into the model's codes by its encoder graph."""

    joints: list[list[Joint]] | None = Field(
        None, min_length=2, max_length=MAX_UPLOAD_FRAMES,
        description="[T][22][3] joint positions in metres, Y up, the SMPL-22 joints in the order of an answer's "
                    "`joints` (as /generate answers them).")
    fps: float | None = Field(None, ge=1.0, le=MAX_UPLOAD_FPS,
                              description="The joints' frame rate (null: 20); resampled to the model's. Not with bvh "
                                          "(its Frame Time says it).")
    bvh: Annotated[str, StringConstraints(min_length=1, max_length=MAX_BVH_CHARS)] | None = Field(
        None, description="The text of a BVH file with this service's skeleton (its bvh answers: SMPL-22 joints "
                          "named as t2m/motion/bvh_export.py names them, centimetres).")
    segments: list[UploadSegment] | None = Field(
        None, min_length=1, max_length=MAX_SEGMENTS,
        description="Its segments in order (texts and frame counts); null: as few equal segments as the model's "
                    "longest segment allows, each with the text 'uploaded motion'.")
    seed: Seed = Field(0, description="The seed the edits derive theirs from where they give none (a handle's seed).")

    @model_validator(mode="after")
    def _one_source(self) -> UploadedMotion:
        if (self.joints is None) == (self.bvh is None):
            raise ValueError("give exactly one of `joints` and `bvh`")
        if self.bvh is not None and self.fps is not None:
            raise ValueError("`fps` goes with `joints`; a BVH file's Frame Time gives its frame rate")
        return self


class EditRequest(StrictModel):
    """POST /edit: change some segments of a motion (one the service made: `handle`; or one the user brings:
    `motion`) and keep the others' codes."""

    handle: Annotated[str, StringConstraints(min_length=1, max_length=MAX_HANDLE_CHARS)] | None = Field(
        None, description="The `handle` of a json answer of /generate or /edit (or give `motion`).")
    motion: UploadedMotion | None = Field(
        None, description="Instead of a handle: a motion to encode with the model's encoder graph (encoder.onnx; a "
                          "model without one answers 422). It is edited as the handle of its codes would be.")
    edits: list[Edit] = Field(
        default_factory=list, max_length=MAX_SEGMENTS,
        description="What to change: regenerate edits ({segment, text?, seed?, duration?}, each segment at most "
                    "once), continue edits ({op: append | prepend, segments, seed?}), in-between edits ({op: "
                    "in_between, after, text, duration, seed?}) and body-part edits ({op: body_part, segment, part, "
                    "text?, start?, end?, seed?}); a family answers 422 at `op` for a kind it does not support "
                    "(/health `extra.edits`). Empty: the handle's motion "
                    "again, bit for bit (e.g. in another format).")
    format: OutputFormat = Field("json", description="json (joints, with the new handle), bvh or glb.")
    model: ModelName | None = Field(None, description="The served model to use; null = the handle's own (for an "
                                                      "uploaded motion: the default model). Either way it must be "
                                                      "the model (name and version) that made the handle.")

    @model_validator(mode="after")
    def _one_motion(self) -> EditRequest:
        if (self.handle is None) == (self.motion is None):
            raise ValueError("give exactly one of `handle` (a motion the service made) and `motion` (an upload)")
        return self

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True, json_schema_extra={"examples": [
        {"handle": "t2m1....", "edits": [{"segment": 1, "text": "a person raises the left hand"}]},
        {"handle": "t2m1....", "edits": [{"segment": 0, "seed": 7}, {"segment": 2, "duration": 4.0}]},
        {"handle": "t2m1....", "edits": [{"op": "append", "segments": [{"text": "a person sits down",
                                                                        "duration": 3.0}]}], "format": "bvh"},
        {"handle": "t2m1....", "edits": [{"op": "in_between", "after": 0, "text": "a person turns around",
                                          "duration": 2.0}]},
        {"handle": "t2m1....", "edits": [{"op": "body_part", "segment": 0, "part": "upper_body",
                                          "text": "a person waves with the right hand"}]},
        {"motion": {"bvh": "HIERARCHY\nROOT Pelvis\n...", "segments": [{"text": "a person walks", "frames": 60}]},
         "edits": [{"op": "append", "segments": [{"text": "a person sits down", "duration": 3.0}]}]}]})


class EditedSegment(BaseModel):
    segment: int = Field(description="Index in the answer's segments.")
    seed: int = Field(description="The seed it was sampled with (send it back to get the same segment again).")


class EditResponse(MotionResponse):
    """The json answer of POST /edit: the whole edited motion, as /generate answers it, and which segments were
    sampled (the others' codes are the handle's); `seed` is the handle's."""

    edited: list[EditedSegment] = Field(default_factory=list)
