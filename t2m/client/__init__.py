"""The t2m Python SDK: `T2MClient` / `AsyncT2MClient` over httpx. Imports nothing of the service."""
from t2m.client.client import AsyncT2MClient, T2MClient
from t2m.client.errors import AuthError, OverloadedError, ServerError, T2MConnectionError, T2MError, ValidationError
from t2m.client.models import (
    Append,
    BodyPart,
    FrameChunk,
    Health,
    InBetween,
    ModelInfo,
    Motion,
    Prepend,
    RawResult,
    Regenerate,
    Segment,
    SegmentSpan,
    Upload,
)

__all__ = [
           "Append",
           "AsyncT2MClient",
           "AuthError",
           "BodyPart",
           "FrameChunk",
           "Health",
           "InBetween",
           "ModelInfo",
           "Motion",
           "OverloadedError",
           "Prepend",
           "RawResult",
           "Regenerate",
           "Segment",
           "SegmentSpan",
           "ServerError",
           "T2MClient",
           "T2MConnectionError",
           "T2MError",
           "Upload",
           "ValidationError",
]
