"""GET /health's answer: the served models' facts and what a request may ask of each."""
from __future__ import annotations

from typing import Any, Literal

from pydantic import (
    BaseModel,
    Field,
)

from t2m import __version__
from t2m.api.answers import ModelInfo
from t2m.runtime.limits import (
    MAX_DURATION_S,
    MAX_GUIDANCE,
    MAX_SEED,
    MAX_SEGMENTS,
    MAX_TEMPERATURE,
    MAX_TEXT_CHARS,
    MAX_TOTAL_S,
    MIN_DURATION_S,
)
from t2m.runtime.types import ModelLimits


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


def request_limits(limits: ModelLimits, max_body_bytes: int, request_timeout_s: float) -> RequestLimits:
    """The limits of a request to the model of `limits` (the fields' own and the model's), as /health shows them."""
    return RequestLimits(
        max_segments=MAX_SEGMENTS, max_text_chars=MAX_TEXT_CHARS, min_duration_s=MIN_DURATION_S,
        max_duration_s=min(MAX_DURATION_S, limits.max_segment_seconds), null_duration=limits.null_duration,
        null_duration_ends_by=limits.ends_segments, max_total_s=MAX_TOTAL_S, max_guidance=MAX_GUIDANCE,
        max_temperature=MAX_TEMPERATURE, max_top_k=limits.codebook_size, max_seed=MAX_SEED,
        max_body_bytes=max_body_bytes, request_timeout_s=request_timeout_s)
