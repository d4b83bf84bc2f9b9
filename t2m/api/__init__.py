"""The API's request and answer models (pydantic, no FastAPI), one module per endpoint: the HTTP service validates
and publishes them as OpenAPI, and the CLI validates `t2m generate` and `t2m edit` with the same ones. The limits
that do not depend on the model live in t2m.runtime.limits; those that do are checked against the model a request picks
(generate.model_limit_errors)."""
from t2m.api.answers import ErrorResponse, ModelInfo, MotionResponse, SegmentSpanOut
from t2m.api.common import ModelName, OutputFormat, Seed, StrictModel, Text, TopK, field_error, json_integer
from t2m.api.edit import (
    BodyPartEdit,
    ContinueEdit,
    Edit,
    EditedSegment,
    EditRequest,
    EditResponse,
    InBetweenEdit,
    Joint,
    RegenerateEdit,
    UploadedMotion,
    UploadSegment,
)
from t2m.api.generate import GenerateRequest, Segment, model_limit_errors, to_generation_request, unknown_model_error
from t2m.api.health import HealthResponse, ModelDetails, RequestLimits, request_limits

__all__ = [
    "BodyPartEdit",
    "ContinueEdit",
    "Edit",
    "EditRequest",
    "EditResponse",
    "EditedSegment",
    "ErrorResponse",
    "GenerateRequest",
    "HealthResponse",
    "InBetweenEdit",
    "Joint",
    "ModelDetails",
    "ModelInfo",
    "ModelName",
    "MotionResponse",
    "OutputFormat",
    "RegenerateEdit",
    "RequestLimits",
    "Seed",
    "Segment",
    "SegmentSpanOut",
    "StrictModel",
    "Text",
    "TopK",
    "UploadSegment",
    "UploadedMotion",
    "field_error",
    "json_integer",
    "model_limit_errors",
    "request_limits",
    "to_generation_request",
    "unknown_model_error",
]
