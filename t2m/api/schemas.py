"""The HTTP API, defined once as pydantic models: FastAPI validates requests with them and publishes them as OpenAPI.

Limits that do not depend on the model are declared on the fields (so they show up in the schema); the ones that do
(`top_k` <= the codebook size, durations within max_tokens, free-length segments counted at the model's longest
segment) are checked against the model the request picks (`model`, by manifest name; null = the default) by
`model_limit_errors`, which reports them in the same shape as pydantic's errors (a `loc` naming the field), as
`unknown_model_error` does for a name no served model has.
"""
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
    ValidationInfo,
    field_validator,
    model_validator,
)

from t2m import __version__
from t2m.runtime.limits import (
    MAX_BVH_CHARS,
    MAX_DURATION_S,
    MAX_GUIDANCE,
    MAX_HANDLE_CHARS,
    MAX_MODEL_NAME_CHARS,
    MAX_SEED,
    MAX_SEGMENTS,
    MAX_TEMPERATURE,
    MAX_TEXT_CHARS,
    MAX_TOTAL_S,
    MAX_UPLOAD_FPS,
    MAX_UPLOAD_FRAMES,
    MIN_DURATION_S,
)
from t2m.runtime.types import GenerationRequest, ModelLimits, SegmentRequest, tokens_for_duration

__all__ = [
    "MAX_DURATION_S",
    "MAX_GUIDANCE",
    "MAX_MODEL_NAME_CHARS",
    "MAX_SEED",
    "MAX_SEGMENTS",
    "MAX_TEMPERATURE",
    "MAX_TEXT_CHARS",
    "MAX_TOTAL_S",
    "MAX_UPLOAD_FPS",
    "MAX_UPLOAD_FRAMES",
    "MIN_DURATION_S",
    "BodyPartEdit",
    "ContinueEdit",
    "EditRequest",
    "EditResponse",
    "EditedSegment",
    "ErrorResponse",
    "GenerateRequest",
    "HealthResponse",
    "InBetweenEdit",
    "ModelDetails",
    "ModelInfo",
    "MotionResponse",
    "OutputFormat",
    "RegenerateEdit",
    "RequestLimits",
    "Segment",
    "SegmentSpanOut",
    "UploadSegment",
    "UploadedMotion",
    "model_limit_errors",
    "request_limits",
    "to_generation_request",
    "unknown_model_error",
]


OutputFormat = Literal["json", "bvh", "glb"]


def _json_integer(value: Any) -> Any:
    """JSON Schema counts 3.0 as an integer; pass it on as 3 (1.5, true and "3" still fail the strict int check)."""
    if isinstance(value, float) and value.is_integer():
        return int(value)
    return value


Seed = Annotated[int, Field(ge=0, le=MAX_SEED), BeforeValidator(_json_integer)]
TopK = Annotated[int, Field(ge=1), BeforeValidator(_json_integer)]


class _Strict(BaseModel):
    """Unknown fields refused, and no type coercion ("3" or true for a number), exactly as the JSON schema says."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)


class Segment(_Strict):
    """One sentence and how long its motion lasts."""

    text: Annotated[
        str, StringConstraints(strip_whitespace=True, min_length=1, max_length=MAX_TEXT_CHARS, pattern=r"\S"),
    ] = Field(
        description=f"What the person does; 1-{MAX_TEXT_CHARS} characters after trimming, not only white space.",
        examples=["a person walks forward"])
    duration: float | None = Field(
        None, ge=MIN_DURATION_S, le=MAX_DURATION_S,
        description=f"Seconds ({MIN_DURATION_S}-{MAX_DURATION_S}); null lets the model end the segment itself "
                    "(GET /health: `limits.null_duration`). Frames = round(duration * fps), fps = 20.",
        examples=[3.0])


class GenerateRequest(_Strict):
    """POST /generate: a stream of sentences that becomes one continuous motion."""

    segments: list[Segment] = Field(
        min_length=1, max_length=MAX_SEGMENTS,
        description=f"1-{MAX_SEGMENTS} segments; total at most {MAX_TOTAL_S:g} s, a null duration counting as the "
                    "model's longest segment (GET /health: `max_segment_seconds`, 10 s for the embedded models).")
    format: OutputFormat = Field("json", description="json (joints), bvh (text) or glb (glTF binary).")
    seed: Seed | None = Field(None,
                             description="Same seed + same request = same motion; null picks one and returns it.")
    guidance: float | None = Field(
        None, ge=0.0, le=MAX_GUIDANCE,
        description="Classifier-free guidance scale (1 = off); null = the model's default.")
    temperature: float = Field(1.0, gt=0.0, le=MAX_TEMPERATURE, description="Sampling temperature.")
    top_k: TopK | None = Field(None, description="Sample among the k most likely codes (<= codebook size).")
    model: Annotated[str, StringConstraints(min_length=1, max_length=MAX_MODEL_NAME_CHARS)] | None = Field(
        None, description="The served model to use, by its manifest name (GET /health lists them under `models`); "
                          "null = the default model.", examples=["t2m-bandai-minilm"])
    stream: bool = Field(
        False, description="true: the answer is newline-delimited JSON (application/x-ndjson): a `start` message, "
                           "`frames` messages as the frames become final, then an `end` message with the rest of the "
                           "json answer (segments, seed, model, warnings). Only the json format streams.")

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True, json_schema_extra={"examples": [{
        "segments": [{"text": "a person walks forward", "duration": 3.0},
                     {"text": "a person waves with the right hand", "duration": 2.0}],
        "format": "json", "seed": 123, "guidance": 3.0, "temperature": 1.0, "top_k": None}]})

    @field_validator("stream")
    @classmethod
    def _only_json_streams(cls, stream: bool, info: ValidationInfo) -> bool:
        """BVH and glb are whole files (a BVH header states the frame count; a glb's binary chunk is sized)."""
        if stream and info.data.get("format", "json") != "json":
            raise ValueError(f"only the json format streams; format {info.data['format']!r} is a whole file "
                             "(send stream false or leave it out)")
        return stream

    @field_validator("segments")
    @classmethod
    def _total_duration(cls, segments: list[Segment]) -> list[Segment]:
        """The fixed durations alone must fit; free segments are added by `model_limit_errors`."""
        total = sum(segment.duration or 0.0 for segment in segments)
        if total > MAX_TOTAL_S:
            raise ValueError(f"total duration {total:g} s exceeds {MAX_TOTAL_S:g} s")
        return segments


ModelName = Annotated[str, StringConstraints(min_length=1, max_length=MAX_MODEL_NAME_CHARS)]
Text = Annotated[str, StringConstraints(strip_whitespace=True, min_length=1, max_length=MAX_TEXT_CHARS, pattern=r"\S")]


class RegenerateEdit(_Strict):
    """Sample one segment of the handle's motion again, with a new text, seed and/or duration."""

    op: Literal["regenerate"] = Field("regenerate", description="This kind of edit (the default).")
    segment: Annotated[int, Field(ge=0), BeforeValidator(_json_integer)] = Field(
        description="Index of the segment in the handle (0 = the first).", examples=[1])
    text: Text | None = Field(None, description="Its new text; null keeps the segment's own.",
                              examples=["a person raises the left hand"])
    seed: Seed | None = Field(None, description="Its seed; null derives one from the handle's seed and the segment's "
                                                "index (the same on every call: send a seed to re-roll).")
    duration: float | None = Field(None, ge=MIN_DURATION_S, le=MAX_DURATION_S,
                                   description="Its new duration in seconds; null keeps the segment's own.")


class ContinueEdit(_Strict):
    """Add segments after (append) or before (prepend) the handle's motion; its own segments are kept."""

    op: Literal["append", "prepend"]
    segments: list[Segment] = Field(min_length=1, max_length=MAX_SEGMENTS)
    seed: Seed | None = Field(None, description="The new segments are sampled as one request with this seed (as "
                                                "/generate samples its segments); null derives one from the handle's "
                                                "seed and the op.")


class InBetweenEdit(_Strict):
    """Fill a gap at the join after segment `after` with a new segment of this text and duration, keeping both
    sides (a family whose loop inpaints: the masked and diffusion families)."""

    op: Literal["in_between"]
    after: Annotated[int, Field(ge=0), BeforeValidator(_json_integer)] = Field(
        description="The new segment goes between segment `after` and segment `after + 1` of the handle.",
        examples=[0])
    text: Text = Field(description="What happens in the gap.", examples=["a person turns around"])
    duration: float = Field(ge=MIN_DURATION_S, le=MAX_DURATION_S, description="The gap's length in seconds.")
    seed: Seed | None = Field(None, description="Its seed; null derives one from the handle's seed and `after`.")


class BodyPartEdit(_Strict):
    """Regenerate some joints of one segment (over all of it, or from `start` to `end` seconds into it), keeping the
    other joints' tokens (a joint-token masked model) or feature channels (a diffusion model: /health `extra.edits`
    lists body_part)."""

    op: Literal["body_part"]
    segment: Annotated[int, Field(ge=0), BeforeValidator(_json_integer)] = Field(
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


class UploadSegment(_Strict):
    """A stretch of an uploaded motion and what happens in it (the text a regenerate edit keeps)."""

    text: Text = Field(description="What happens in these frames.", examples=["a person walks forward"])
    frames: Annotated[int, Field(ge=1, le=MAX_UPLOAD_FRAMES), BeforeValidator(_json_integer)] = Field(
        description="How many of the upload's frames (at its own frame rate) it covers; the segments' frames add up "
                    "to the upload's.")


Joint = Annotated[list[float], Field(min_length=3, max_length=3)]


class UploadedMotion(_Strict):
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


class EditRequest(_Strict):
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


class SegmentSpanOut(BaseModel):
    text: str
    start_frame: int = Field(description="First frame of the segment.")
    end_frame: int = Field(description="One past the last frame (exclusive), = the next segment's start_frame.")


class ModelInfo(BaseModel):
    name: str
    version: str


class MotionResponse(BaseModel):
    """The json answer: joint positions in metres, Y up, first frame facing +Z."""

    fps: int
    joints: list[str] = Field(description="The 22 SMPL joint names, in the order of frames' second axis.")
    parents: list[int] = Field(description="Parent index of each joint (-1 for the root).")
    frames: list[list[list[float]]] = Field(description="[T][22][3] positions in metres.")
    segments: list[SegmentSpanOut]
    seed: int
    model: ModelInfo
    warnings: list[str] = Field(default_factory=list)
    handle: str | None = Field(
        None, description="The motion's codes, segments and options in one compact string (`t2m1.` + base64url; "
                          "docs/api.md): send it to POST /edit to change some segments and keep the others. A "
                          "diffusion model's is its recipe instead (`t2m2.`: seed, guidance, segments and the edits "
                          "made since, which make its frames again exactly).")


class EditResponse(MotionResponse):
    """The json answer of POST /edit: the whole edited motion, as /generate answers it, and which segments were
    sampled (the others' codes are the handle's); `seed` is the handle's."""

    edited: list[EditedSegment] = Field(default_factory=list)


class RequestLimits(BaseModel):
    """What a request to one model may ask (each violation is a 422 naming the field): what a client needs to plan
    one without trial and error."""

    max_segments: int = Field(description="Segments per request at most.")
    max_text_chars: int = Field(description="Characters of a segment's text at most, after trimming.")
    min_duration_s: float = Field(description="A segment's shortest duration.")
    max_duration_s: float = Field(description="A segment's longest duration for this model: the API's cap or the "
                                              "model's longest segment, whichever is shorter.")
    null_duration: bool = Field(description="Whether a segment may leave `duration` null and let the model end it.")
    null_duration_ends_by: str | None = Field(description="How the model ends such a segment (its End token, stop "
                                                          "head or length estimator); null when it cannot.")
    max_total_s: float = Field(description="All durations together at most; a null duration counts as "
                                           "`max_segment_seconds`.")
    max_guidance: float
    max_temperature: float = Field(description="Temperatures are in (0, max_temperature].")
    max_top_k: int = Field(description="`top_k` is 1..the codebook size.")
    max_seed: int
    max_body_bytes: int = Field(description="Larger request bodies answer 413 (T2M_MAX_BODY_BYTES).")
    request_timeout_s: float = Field(description="A generation taking longer answers 504 (T2M_REQUEST_TIMEOUT_S).")


class ModelDetails(ModelInfo):
    fps: int = Field(description="Frames per second of the answer.")
    frames_per_token: int = Field(description="Frames the model decodes per code step; a segment's frames in the "
                                              "answer are round(duration * fps) all the same.")
    max_tokens: int = Field(description="Code steps per segment at most.")
    max_segment_seconds: float = Field(description="The longest segment: max_tokens * frames_per_token / fps.")
    codebook_size: int
    default_guidance: float
    unconditional_branch: bool
    length_conditioning: bool
    limits: RequestLimits
    extra: dict[str, Any] = Field(default_factory=dict)


class HealthResponse(BaseModel):
    status: Literal["ok", "loading", "error"]
    service_version: str = Field(__version__, description="t2m-service version (the package's and the API's).")
    model: ModelDetails | None = Field(None, description="The default model (the one a request without `model` gets).")
    models: list[ModelDetails] = Field(default_factory=list,
                                       description="Every served model, the default first; `name` is what a request's "
                                                   "`model` field takes.")
    default: str | None = Field(None, description="The default model's name.")
    detail: str | None = None


class ErrorResponse(BaseModel):
    detail: str


def request_limits(limits: ModelLimits, max_body_bytes: int, request_timeout_s: float) -> RequestLimits:
    """The limits of a request to the model of `limits` (the fields' own and the model's), as /health shows them."""
    return RequestLimits(
        max_segments=MAX_SEGMENTS, max_text_chars=MAX_TEXT_CHARS, min_duration_s=MIN_DURATION_S,
        max_duration_s=min(MAX_DURATION_S, limits.max_segment_seconds), null_duration=limits.null_duration,
        null_duration_ends_by=limits.ends_segments, max_total_s=MAX_TOTAL_S, max_guidance=MAX_GUIDANCE,
        max_temperature=MAX_TEMPERATURE, max_top_k=limits.codebook_size, max_seed=MAX_SEED,
        max_body_bytes=max_body_bytes, request_timeout_s=request_timeout_s)


def _error(loc: tuple[Any, ...], message: str, value: Any) -> dict[str, Any]:
    """An error in pydantic's shape so that FastAPI's 422 handler and our callers treat it the same way."""
    return {"type": "value_error", "loc": loc, "msg": message, "input": value}


def model_limit_errors(request: GenerateRequest, limits: ModelLimits) -> list[dict[str, Any]]:
    """The request's violations of the loaded model's limits, each with the `loc` of the offending field."""
    errors: list[dict[str, Any]] = []
    if request.top_k is not None and request.top_k > limits.codebook_size:
        errors.append(_error(("body", "top_k"), f"top_k must be at most the codebook size {limits.codebook_size}",
                             request.top_k))
    for index, segment in enumerate(request.segments):
        if segment.duration is None:
            continue
        tokens = tokens_for_duration(segment.duration, limits.fps, limits.frames_per_token)
        if tokens > limits.max_tokens:
            errors.append(_error(
                ("body", "segments", index, "duration"),
                f"duration {segment.duration:g} s needs {tokens} tokens; this model makes at most "
                f"{limits.max_tokens} per segment ({limits.max_segment_seconds:g} s)", segment.duration))
    total = sum(s.duration if s.duration is not None else limits.max_segment_seconds for s in request.segments)
    if total > MAX_TOTAL_S + 1e-9:
        errors.append(_error(
            ("body", "segments"),
            f"total duration {total:g} s exceeds {MAX_TOTAL_S:g} s (a null duration counts as "
            f"{limits.max_segment_seconds:g} s, the model's longest segment)", None))
    return errors


def unknown_model_error(name: str, available: list[str]) -> dict[str, Any]:
    """The 422 error for a `model` no served model is called, listing the names that exist."""
    return _error(("body", "model"), f"no model named {name!r}; this service serves "
                  f"{', '.join(repr(known) for known in available)}", name)


def to_generation_request(request: GenerateRequest, limits: ModelLimits, seed: int) -> GenerationRequest:
    """Resolve the request's defaults against the model: the engine gets every choice made."""
    guidance = limits.guidance(request.guidance)
    return GenerationRequest(
        segments=[SegmentRequest(text=s.text, duration=s.duration) for s in request.segments],
        seed=seed, guidance=float(guidance), temperature=float(request.temperature), top_k=request.top_k)
