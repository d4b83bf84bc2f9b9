"""GET /metrics: Prometheus text exposition of this instance's metrics."""
from __future__ import annotations

from fastapi import APIRouter, Depends, Response
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from t2m.service.dependencies import ServiceState, get_state

__all__ = ["router"]

router = APIRouter(tags=["operations"])


@router.get("/metrics", response_class=Response, responses={200: {"content": {CONTENT_TYPE_LATEST: {}}}})
def metrics(state: ServiceState = Depends(get_state)) -> Response:
    """Requests by route/status, latency histogram, tokens generated, queue depth, in-flight requests."""
    return Response(generate_latest(state.metrics.registry), media_type=CONTENT_TYPE_LATEST)
