"""POST /generate: sentences with durations -> one continuous motion as json, BVH or glb; with `"stream": true` the
json answer comes as newline-delimited JSON, its frames sent as they become final (service/streaming.py)."""
from __future__ import annotations

import logging
import secrets
import time
from collections.abc import AsyncIterator
from typing import Any

from fastapi import APIRouter, Depends, HTTPException, Response, status
from fastapi.exceptions import RequestValidationError
from fastapi.responses import StreamingResponse
from starlette.concurrency import run_in_threadpool

from t2m.api import (
    ErrorResponse,
    GenerateRequest,
    MotionResponse,
    model_limit_errors,
    to_generation_request,
    unknown_model_error,
)
from t2m.runtime.formats import (
    STREAM_MEDIA_TYPE,
    ndjson,
    render,
    stream_end,
    stream_error,
    stream_frames,
    stream_start,
)
from t2m.runtime.frame_stream import MotionStream
from t2m.runtime.handles import answer_handle
from t2m.runtime.scheduling import GenerationTimeout, QueueFullError
from t2m.runtime.served_models import ServedModel
from t2m.runtime.types import GenerationCancelled, GenerationRequest, ModelLimits, Motion, RequestLimitError
from t2m.service.dependencies import ServiceState, ready_state, require_api_key
from t2m.service.settings import Settings

__all__ = ["RANDOM_SEED_BITS", "STREAM_CHUNK_FRAMES", "http_error", "motion_answer", "router"]

RANDOM_SEED_BITS = 31   # seeds we pick fit any client's integers (JavaScript included)
STREAM_CHUNK_FRAMES = 40   # frames per message of what is sent with the whole motion (2 s at 20 fps)

log = logging.getLogger(__name__)

router = APIRouter(tags=["generation"])

ERROR_RESPONSES: dict[int | str, dict[str, Any]] = {
    200: {"description": "The motion. json: MotionResponse; bvh: BVH text; glb: glTF binary. "
                         "Headers: X-Seed (the seed used), X-T2M-Warnings (if any; a stream has its warnings in its "
                         "end message). With stream: true, newline-delimited JSON: {type: start, fps, joints, "
                         "parents, model, seed}, then {type: frames, start_frame, frames} messages, then "
                         "{type: end, ...the json answer without frames, frame_count} or, if the generation fails "
                         "after the first frames, {type: error, status, detail}.",
          "content": {"text/plain": {"schema": {"type": "string"}},
                      "model/gltf-binary": {"schema": {"type": "string", "format": "binary"}},
                      STREAM_MEDIA_TYPE: {"schema": {"type": "string"}}}},
    400: {"model": ErrorResponse, "description": "The body could not be read (e.g. it is not UTF-8)."},
    401: {"model": ErrorResponse, "description": "Missing or wrong API key (when T2M_API_KEY is set)."},
    413: {"model": ErrorResponse, "description": "Request body larger than T2M_MAX_BODY_BYTES."},
    429: {"model": ErrorResponse, "description": "Too many requests waiting; see Retry-After."},
    503: {"model": ErrorResponse, "description": "The model is loading (or failed to load); see Retry-After."},
    504: {"model": ErrorResponse, "description": "Generation took longer than T2M_REQUEST_TIMEOUT_S."},
}


@router.post("/generate", response_model=MotionResponse, responses=ERROR_RESPONSES,
             dependencies=[Depends(require_api_key)], summary="Generate a motion from sentences")
async def generate(body: GenerateRequest, state: ServiceState = Depends(ready_state)) -> Response:
    """Each segment's text becomes `duration` seconds of motion (or as long as the model decides when null),
    the segments following each other without a seam. The answer's `segments` give each sentence's frames.
    `model` picks a served model by name (GET /health lists them); without it the default model answers.
    `stream` (json only) sends the frames as they become final."""
    started = time.perf_counter()
    settings = state.settings
    assert state.models is not None
    model = state.models.get(body.model)
    if model is None:
        raise RequestValidationError([unknown_model_error(str(body.model), state.models.names)])
    limits = model.limits
    errors = model_limit_errors(body, limits)
    if errors:
        raise RequestValidationError(errors)
    seed = body.seed if body.seed is not None else secrets.randbits(RANDOM_SEED_BITS)
    request = to_generation_request(body, limits, seed)
    if body.stream:
        return await _stream(model, request, state, started)
    try:
        motion = await model.batcher.generate(request, settings.request_timeout_s)
    except Exception as error:
        raise http_error(error, settings) from None
    state.metrics.count_generation(model.name, motion.tokens, len(motion.segments))

    return await motion_answer(motion, body.format, limits, request)


async def motion_answer(motion: Motion, fmt: str, limits: ModelLimits, request: GenerationRequest,
                        extra: dict[str, Any] | None = None) -> Response:
    """The answer of a motion made for `request` (its json with the handle and `extra`'s fields, or the file), with
    its headers: X-Seed (the request's), X-T2M-Warnings, a file's Content-Disposition."""
    handle = answer_handle(limits, request, motion) if fmt == "json" else None
    rendered = await run_in_threadpool(render, motion, fmt, limits, handle, extra)
    headers = {"X-Seed": str(request.seed)}
    if motion.warnings:
        # headers are latin-1: anything else (e.g. a model name) becomes '?'
        headers["X-T2M-Warnings"] = " | ".join(motion.warnings).encode("ascii", "replace").decode()
    if fmt != "json":
        headers["Content-Disposition"] = f'attachment; filename="{rendered.filename}"'
    return Response(content=rendered.body, media_type=rendered.media_type, headers=headers)


def http_error(error: Exception, settings: Settings) -> Exception:
    """The HTTP answer for a failed generation; an error without one (an engine failure) is itself, a 500."""
    if isinstance(error, QueueFullError):
        return HTTPException(status.HTTP_429_TOO_MANY_REQUESTS, detail=f"server busy: {error}",
                             headers={"Retry-After": str(settings.retry_after_s)})
    if isinstance(error, GenerationTimeout):
        return HTTPException(status.HTTP_504_GATEWAY_TIMEOUT,
                             detail=f"{error} (T2M_REQUEST_TIMEOUT_S); try shorter segments")
    if isinstance(error, GenerationCancelled):
        return HTTPException(status.HTTP_503_SERVICE_UNAVAILABLE, detail=str(error),
                             headers={"Retry-After": str(settings.retry_after_s)})
    if isinstance(error, RequestLimitError):   # a limit the engine checks itself, at the field it names
        return RequestValidationError([{"type": "value_error", "loc": ("body", *error.location), "msg": str(error),
                                        "input": None}])
    return error


async def _stream(model: ServedModel, request: GenerationRequest, state: ServiceState,
                  started: float) -> StreamingResponse:
    """Wait for the first frames (or the whole motion), so that whatever fails before them is an ordinary error
    answer; then answer 200 with the stream."""
    stream: MotionStream | None = None
    try:
        stream = MotionStream(model.batcher, request, state.settings.request_timeout_s)
        first = await stream.next()
    except Exception as error:
        if stream is not None:
            stream.close()
        raise http_error(error, state.settings) from None
    state.metrics.first_frame.labels(model.name).observe(time.perf_counter() - started)
    # X-Accel-Buffering: a proxy such as nginx passes each message on at once instead of buffering the answer
    headers = {"X-Seed": str(request.seed), "Cache-Control": "no-store", "X-Accel-Buffering": "no"}
    return StreamingResponse(_messages(stream, first, model, state), media_type=STREAM_MEDIA_TYPE, headers=headers)


async def _messages(stream: MotionStream, first: Any, model: ServedModel,
                    state: ServiceState) -> AsyncIterator[bytes]:
    """start, frames as the engine sends them, the rest of the whole motion in chunks, end (or error). Leaving early
    (the client went away) cancels the generation."""
    limits = model.limits
    try:
        yield ndjson(stream_start(limits, stream.request.seed))
        item, sent = first, 0
        while not isinstance(item, Motion):
            yield ndjson(stream_frames(sent, item))
            sent += len(item)
            item = await stream.next()
        for start in range(sent, len(item.joints), STREAM_CHUNK_FRAMES):
            yield ndjson(stream_frames(start, item.joints[start:start + STREAM_CHUNK_FRAMES]))
        state.metrics.count_generation(model.name, item.tokens, len(item.segments))
        yield ndjson(stream_end(item, limits, answer_handle(limits, stream.request, item)))
    except Exception as error:   # the 200 has gone out: the failure can only be told in the stream
        answer = http_error(error, state.settings)
        if isinstance(answer, HTTPException):
            yield ndjson(stream_error(answer.status_code, str(answer.detail)))
        else:
            log.error("streamed generation failed", exc_info=error)
            yield ndjson(stream_error(status.HTTP_500_INTERNAL_SERVER_ERROR, "internal server error"))
    finally:
        stream.close()
