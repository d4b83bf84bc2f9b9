"""POST /generate's request (its fields and their limits) and the checks of a request against the model it picks (a 422
at the field, as pydantic reports its own)."""
from __future__ import annotations

from typing import Annotated, Any

from pydantic import (
    ConfigDict,
    Field,
    StringConstraints,
    ValidationInfo,
    field_validator,
)

from t2m.api.common import OutputFormat, Seed, StrictModel, TopK, field_error
from t2m.runtime.limits import (
    MAX_DURATION_S,
    MAX_GUIDANCE,
    MAX_MODEL_NAME_CHARS,
    MAX_SEGMENTS,
    MAX_TEMPERATURE,
    MAX_TEXT_CHARS,
    MAX_TOTAL_S,
    MIN_DURATION_S,
)
from t2m.runtime.types import GenerationRequest, ModelLimits, SegmentRequest, tokens_for_duration


class Segment(StrictModel):
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


class GenerateRequest(StrictModel):
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


def model_limit_errors(request: GenerateRequest, limits: ModelLimits) -> list[dict[str, Any]]:
    """The request's violations of the loaded model's limits, each with the `loc` of the offending field."""
    errors: list[dict[str, Any]] = []
    if request.top_k is not None and request.top_k > limits.codebook_size:
        errors.append(field_error(("body", "top_k"), f"top_k must be at most the codebook size {limits.codebook_size}",
                             request.top_k))
    for index, segment in enumerate(request.segments):
        if segment.duration is None:
            continue
        tokens = tokens_for_duration(segment.duration, limits.fps, limits.frames_per_token)
        if tokens > limits.max_tokens:
            errors.append(field_error(
                ("body", "segments", index, "duration"),
                f"duration {segment.duration:g} s needs {tokens} tokens; this model makes at most "
                f"{limits.max_tokens} per segment ({limits.max_segment_seconds:g} s)", segment.duration))
    total = sum(s.duration if s.duration is not None else limits.max_segment_seconds for s in request.segments)
    if total > MAX_TOTAL_S + 1e-9:
        errors.append(field_error(
            ("body", "segments"),
            f"total duration {total:g} s exceeds {MAX_TOTAL_S:g} s (a null duration counts as "
            f"{limits.max_segment_seconds:g} s, the model's longest segment)", None))
    return errors


def unknown_model_error(name: str, available: list[str]) -> dict[str, Any]:
    """The 422 error for a `model` no served model is called, listing the names that exist."""
    return field_error(("body", "model"), f"no model named {name!r}; this service serves "
                  f"{', '.join(repr(known) for known in available)}", name)


def to_generation_request(request: GenerateRequest, limits: ModelLimits, seed: int) -> GenerationRequest:
    """Resolve the request's defaults against the model: the engine gets every choice made."""
    guidance = limits.guidance(request.guidance)
    return GenerationRequest(
        segments=[SegmentRequest(text=s.text, duration=s.duration) for s in request.segments],
        seed=seed, guidance=float(guidance), temperature=float(request.temperature), top_k=request.top_k)
