"""GET /health: 200 with every served model's facts once all are loaded, 503 while loading or after a failed load."""
from __future__ import annotations

from fastapi import APIRouter, Depends
from fastapi.responses import JSONResponse

from t2m.api import HealthResponse, ModelDetails, request_limits
from t2m.runtime.served_models import ServedModel
from t2m.service.dependencies import ServiceState, get_state
from t2m.service.settings import Settings

__all__ = ["router"]

router = APIRouter(tags=["operations"])


@router.get("/health", response_model=HealthResponse,
            responses={503: {"model": HealthResponse, "description": "Loading, or the load failed (see detail)."}})
def health(state: ServiceState = Depends(get_state)) -> JSONResponse:
    """Readiness for load balancers and container health checks. `model` is the default model (as before several
    models could be served); `models` lists every served model, the default first."""
    if state.status != "ok" or state.models is None:
        answer = HealthResponse(status=state.status, detail=state.error if state.status == "error"
                                else "loading the model bundles")
        return JSONResponse(answer.model_dump(), status_code=503,
                            headers={"Retry-After": str(state.settings.retry_after_s)})
    models = [_details(model, state.settings) for model in state.models]
    answer = HealthResponse(status="ok", model=models[0], models=models, default=state.models.default.name)
    return JSONResponse(answer.model_dump())


def _details(model: ServedModel, settings: Settings) -> ModelDetails:
    """One model's facts, with what a client needs to plan a request to it (frames, durations, limits)."""
    limits = model.limits
    return ModelDetails(name=limits.name, version=limits.version, fps=limits.fps,
                        frames_per_token=limits.frames_per_token, max_tokens=limits.max_tokens,
                        max_segment_seconds=limits.max_segment_seconds, codebook_size=limits.codebook_size,
                        default_guidance=limits.default_guidance, unconditional_branch=limits.unconditional_branch,
                        length_conditioning=limits.length_conditioning,
                        limits=request_limits(limits, settings.max_body_bytes, settings.request_timeout_s),
                        extra={**limits.details, "load_seconds": model.load_seconds,
                               "edits": sorted(limits.edits), "uploads": limits.encodes})
