"""POST /edit: a motion the service made (its answer's `handle`) or one the user uploads (`motion`, encoded into
codes: service/uploads.py) with some segments sampled again or added (a gap
filled in between, a body part regenerated, where the family inpaints), the other segments' codes kept, all decoded
once: the frames before the edit and outside the decoder's reach of it are the
handle's bit for bit, the frames after it the same motion rigidly moved (docs/api.md states the exact rule).
Stateless: the handle carries everything (service/handles.py)."""
from __future__ import annotations

import asyncio
from typing import Any

from fastapi import APIRouter, Depends, Response
from fastapi.exceptions import RequestValidationError
from starlette.concurrency import run_in_threadpool

from t2m.api import EditRequest, EditResponse, unknown_model_error
from t2m.runtime.editing import EditError, EditPlan, finish_edit, plan_edit
from t2m.runtime.formats import STREAM_MEDIA_TYPE
from t2m.runtime.handles import HandleError, handle_model, read_handle
from t2m.runtime.scheduling import GenerationTimeout, MicroBatcher, QueueFullError
from t2m.runtime.served_models import ServedModel
from t2m.runtime.types import (
    ComposingEngine,
    EncodingEngine,
    GenerationRequest,
    Motion,
    RecipeEditingEngine,
    RequestLimitError,
    SegmentRequest,
)
from t2m.runtime.uploads import uploaded_handle
from t2m.service.dependencies import ServiceState, ready_state, require_api_key
from t2m.service.routes.generate import ERROR_RESPONSES, http_error, motion_answer

__all__ = ["router"]

router = APIRouter(tags=["generation"])

_EDIT_RESPONSES: dict[int | str, dict[str, Any]] = {
    **ERROR_RESPONSES,
    200: {"description": "The edited motion. json: EditResponse (with a new handle); bvh: BVH text; glb: glTF binary. "
                         "Headers: X-Seed (the handle's seed), X-T2M-Warnings (if any).",
          "content": {media: schema for media, schema in ERROR_RESPONSES[200]["content"].items()
                      if media != STREAM_MEDIA_TYPE}},
}


def _handle_error(error: HandleError) -> RequestValidationError:
    return RequestValidationError([{"type": "value_error", "loc": ("body", "handle"), "msg": str(error),
                                    "input": None}])


def _model_of(body: EditRequest, state: ServiceState) -> ServedModel:
    """The model the body names, else the served model of the name the handle names (its version and everything
    else are checked by read_handle against that model)."""
    assert state.models is not None
    if body.model is not None or body.handle is None:       # an upload without `model`: the default model
        model = state.models.get(body.model)
        if model is None:
            raise RequestValidationError([unknown_model_error(body.model or "", state.models.names)])
        return model
    try:
        name, version = handle_model(body.handle)
    except HandleError as error:
        raise _handle_error(error) from None
    model = state.models.get(name)
    if model is None:
        raise _handle_error(HandleError("handle.model", f"made by model {name!r} version {version!r}, which this "
                                        f"service does not serve ({', '.join(map(repr, state.models.names))})"))
    return model


@router.post("/edit", response_model=EditResponse, responses=_EDIT_RESPONSES, dependencies=[Depends(require_api_key)],
             summary="Edit a motion: regenerate some segments (or a body part), append, prepend or fill a gap "
                     "in between, keep the rest")
async def edit(body: EditRequest, state: ServiceState = Depends(ready_state)) -> Response:
    """`handle` is a json answer's handle (of /generate or /edit). Each regenerate edit samples its segment again (a
    new text, seed or duration); append and prepend edits add segments; an in_between edit fills the join after a
    segment with a new one and a body_part edit regenerates some joints of a segment (a family whose loop inpaints,
    the masked family, fills every edit with the kept codes on both sides as context); every other segment keeps its
    codes, and the codes are decoded once: frames before the edit and outside the decoder's reach are the handle's
    bit for bit, frames after it the same motion rigidly moved (the root's path is a running sum; docs/api.md gives
    the rule). No edits answers the handle's motion again, bit for bit. The model must be the one (name and version)
    that made the handle; a family answers 422 for an edit kind it does not support (GET /health: a model's
    `extra.edits`). Instead of a handle, `motion` uploads a motion (JSON joints or a BVH file, with its segments'
    texts and frames), encoded by the model's encoder.onnx into codes that are then edited as a handle's
    (service/uploads.py; /health `extra.uploads`). A 422 names the field: `handle` for a handle that is corrupted,
    altered, out of the model's ranges or another model's (the message names the part: `handle.checksum`,
    `handle.segments.0.codes`, `handle.model`), `motion...` for an upload the model cannot encode or that is out of
    the limits, `edits.<i>...` for an edit the handle or the model does not allow. A diffusion model's handle is a
    recipe (`t2m2.`: its request and the edits made since, replayed to the same frames) and its edits are made on
    its frames by its own inpainting (docs/api.md)."""
    model = _model_of(body, state)
    limits = model.limits
    if limits.recipe:
        return await _edit_recipe(body, model, state)
    try:
        if body.motion is not None:
            encode = model.engine.encode if isinstance(model.engine, EncodingEngine) else None
            handle = await run_in_threadpool(uploaded_handle, body.motion, limits, encode)
        else:
            assert body.handle is not None
            handle = read_handle(body.handle, limits)
        plan = plan_edit(handle, body.edits, limits)
    except HandleError as error:
        raise _handle_error(error) from None
    except EditError as error:
        raise RequestValidationError([error.error()]) from None
    sampled = await _sample(plan, model, state)
    if not isinstance(model.engine, ComposingEngine):
        raise _handle_error(HandleError("handle", f"model {limits.name!r} cannot decode codes it is given"))
    result = await run_in_threadpool(finish_edit, model.engine, handle, plan, sampled)
    state.metrics.count_generation(model.name, sum(m.tokens for m in sampled), sum(len(m.segments) for m in sampled))
    edited = [{"segment": index, "seed": seed} for index, seed in result.edited]
    return await motion_answer(result.motion, body.format, limits, plan.request(handle), {"edited": edited})

async def _edit_recipe(body: EditRequest, model: ServedModel, state: ServiceState) -> Response:
    """A diffusion model's edit (t2m/families/diffusion/edits.py): the handle is a recipe, replayed and edited on
    the model's frames as one work item of the model's batcher (queued and counted like a request: a 429 when the
    queue is full, a 504 past T2M_REQUEST_TIMEOUT_S, and an edit whose turn comes after that never runs)."""
    if body.handle is None:
        raise RequestValidationError([{"type": "value_error", "loc": ("body", "motion"), "msg": f"model "
                                       f"{model.limits.name!r} is a diffusion model: it edits the motions it made "
                                       "(their handles), not uploads", "input": None}])
    if not isinstance(model.engine, RecipeEditingEngine):
        raise _handle_error(HandleError("handle", f"model {model.limits.name!r} cannot edit a recipe"))
    timeout = state.settings.request_timeout_s
    engine, handle, edits, batcher = model.engine, body.handle, body.edits, model.batcher
    if not isinstance(batcher, MicroBatcher):   # a recipe's model runs batches whole: its family steps no cohorts
        raise TypeError(f"model {model.limits.name!r} edits recipes but its batcher is a {type(batcher).__name__}")
    try:
        result = await batcher.run(lambda: engine.edit_recipe(handle, edits), timeout)
    except GenerationTimeout:
        raise http_error(GenerationTimeout(f"the edit did not finish within {timeout:g} s"), state.settings) from None
    except QueueFullError as error:
        raise http_error(error, state.settings) from None
    except HandleError as error:
        raise _handle_error(error) from None
    except EditError as error:
        raise RequestValidationError([error.error()]) from None
    motion = result.motion
    request = GenerationRequest([SegmentRequest(s.text, None) for s in motion.segments], seed=motion.seed)
    made = [motion.segments[index] for index, _ in result.edited]
    state.metrics.count_generation(model.name, sum(s.end_frame - s.start_frame for s in made), len(made))
    edited = [{"segment": index, "seed": seed} for index, seed in result.edited]
    return await motion_answer(motion, body.format, model.limits, request, {"edited": edited})


async def _sample(plan: EditPlan, model: ServedModel, state: ServiceState) -> list[Motion]:
    """The plan's parts through the model's batcher together (each its own request and seed); one failing cancels
    the others and answers as a failed generation would, its field the edit's."""
    timeout = state.settings.request_timeout_s
    tasks = [asyncio.ensure_future(model.batcher.generate(part.request, timeout)) for part in plan.parts]
    try:
        return list(await asyncio.gather(*tasks))
    except BaseException as error:
        for sampled, task in zip(plan.parts, tasks):
            sampled.request.cancel()
            task.cancel()
        if isinstance(error, RequestLimitError):
            failed = next(i for i, task in enumerate(tasks) if task.done() and not task.cancelled()
                          and task.exception() is error)
            raise RequestValidationError([{"type": "value_error", "loc": plan.field_of(failed, error),
                                           "msg": str(error), "input": None}]) from None
        if isinstance(error, Exception):
            raise http_error(error, state.settings) from None
        raise
