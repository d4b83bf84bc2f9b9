"""POST /generate: sentences with durations -> one continuous motion as json, BVH or glb."""
from __future__ import annotations

import secrets
from typing import Any

from fastapi import APIRouter, Depends, HTTPException, Response, status
from fastapi.exceptions import RequestValidationError
from starlette.concurrency import run_in_threadpool

from t2m.service.batching import GenerationTimeout, QueueFullError
from t2m.service.dependencies import ServiceState, ready_state, require_api_key
from t2m.service.engine.types import GenerationCancelled, RequestLimitError
from t2m.service.formats import render
from t2m.service.schemas import (
    ErrorResponse,
    GenerateRequest,
    MotionResponse,
    model_limit_errors,
    to_generation_request,
    unknown_model_error,
)

__all__ = ["RANDOM_SEED_BITS", "router"]

RANDOM_SEED_BITS = 31   # seeds we pick fit any client's integers (JavaScript included)

router = APIRouter(tags=["generation"])

_RESPONSES: dict[int | str, dict[str, Any]] = {
    200: {"description": "The motion. json: MotionResponse; bvh: BVH text; glb: glTF binary. "
                         "Headers: X-Seed (the seed used), X-T2M-Warnings (if any).",
          "content": {"text/plain": {"schema": {"type": "string"}},
                      "model/gltf-binary": {"schema": {"type": "string", "format": "binary"}}}},
    400: {"model": ErrorResponse, "description": "The body could not be read (e.g. it is not UTF-8)."},
    401: {"model": ErrorResponse, "description": "Missing or wrong API key (when T2M_API_KEY is set)."},
    413: {"model": ErrorResponse, "description": "Request body larger than T2M_MAX_BODY_BYTES."},
    429: {"model": ErrorResponse, "description": "Too many requests waiting; see Retry-After."},
    503: {"model": ErrorResponse, "description": "The model is loading (or failed to load); see Retry-After."},
    504: {"model": ErrorResponse, "description": "Generation took longer than T2M_REQUEST_TIMEOUT_S."},
}


@router.post("/generate", response_model=MotionResponse, responses=_RESPONSES,
             dependencies=[Depends(require_api_key)], summary="Generate a motion from sentences")
async def generate(body: GenerateRequest, state: ServiceState = Depends(ready_state)) -> Response:
    """Each segment's text becomes `duration` seconds of motion (or as long as the model decides when null),
    the segments following each other without a seam. The answer's `segments` give each sentence's frames.
    `model` picks a served model by name (GET /health lists them); without it the default model answers."""
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
    try:
        motion = await model.batcher.generate(request, settings.request_timeout_s)
    except QueueFullError as error:
        raise HTTPException(status.HTTP_429_TOO_MANY_REQUESTS, detail=f"server busy: {error}",
                            headers={"Retry-After": str(settings.retry_after_s)}) from None
    except GenerationTimeout as error:
        raise HTTPException(status.HTTP_504_GATEWAY_TIMEOUT,
                            detail=f"{error} (T2M_REQUEST_TIMEOUT_S); try shorter segments") from None
    except GenerationCancelled as error:
        raise HTTPException(status.HTTP_503_SERVICE_UNAVAILABLE, detail=str(error),
                            headers={"Retry-After": str(settings.retry_after_s)}) from None
    except RequestLimitError as error:  # a limit the engine checks itself; the message starts with the field
        field = str(error).split(":", 1)[0]
        loc = ("body", *(int(part) if part.isdigit() else part for part in field.split(".")))
        raise RequestValidationError([{"type": "value_error", "loc": loc, "msg": str(error), "input": None}]) from None
    state.metrics.count_generation(model.name, motion.tokens, len(motion.segments))

    rendered = await run_in_threadpool(render, motion, body.format, limits)
    headers = {"X-Seed": str(motion.seed)}
    if motion.warnings:
        # headers are latin-1: anything else (e.g. a model name) becomes '?'
        headers["X-T2M-Warnings"] = " | ".join(motion.warnings).encode("ascii", "replace").decode()
    if body.format != "json":
        headers["Content-Disposition"] = f'attachment; filename="{rendered.filename}"'
    return Response(content=rendered.body, media_type=rendered.media_type, headers=headers)
