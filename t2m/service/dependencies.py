"""What the routes share: the service state (models, settings, metrics), the API-key check, readiness."""
from __future__ import annotations

import secrets
import threading
from dataclasses import dataclass, field
from typing import Literal

from fastapi import Depends, HTTPException, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from t2m.runtime.scheduling import QueuedWorkers
from t2m.runtime.served_models import ModelRegistry, ServedModel
from t2m.runtime.types import Engine
from t2m.service.metrics import ServiceMetrics
from t2m.service.settings import Settings

__all__ = ["ServiceState", "get_state", "ready_state", "require_api_key"]


@dataclass
class ServiceState:
    """Everything one app instance owns; the models appear once the background load of every bundle has finished."""

    settings: Settings
    metrics: ServiceMetrics
    status: Literal["loading", "ok", "error"] = "loading"
    models: ModelRegistry | None = None
    error: str | None = None
    load_seconds: float | None = None
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    @property
    def engine(self) -> Engine | None:
        """The default model's engine (None until loaded)."""
        return self.models.default.engine if self.models is not None else None

    @property
    def batcher(self) -> QueuedWorkers | None:
        """The default model's batcher (None until loaded)."""
        return self.models.default.batcher if self.models is not None else None

    def set_ready(self, models: ModelRegistry, load_seconds: float) -> None:
        for model in models:
            self._publish(model)
        with self._lock:
            self.models, self.load_seconds = models, load_seconds
            self.status = "ok"

    def _publish(self, model: ServedModel) -> None:
        """The model's series in /metrics, its queue gauges reading its own batcher."""
        batcher = model.batcher
        self.metrics.add_model(model.name, model.limits.version, lambda: batcher.queue_depth,
                               lambda: batcher.in_flight)

    def set_error(self, message: str) -> None:
        with self._lock:
            self.status, self.error = "error", message


def get_state(request: Request) -> ServiceState:
    return request.app.state.service


def ready_state(state: ServiceState = Depends(get_state)) -> ServiceState:
    """The state of a service whose model is loaded; 503 (with Retry-After) while loading or after a failed load."""
    if state.status == "ok":
        return state
    detail = "the model is still loading" if state.status == "loading" else f"the model failed to load: {state.error}"
    raise HTTPException(status.HTTP_503_SERVICE_UNAVAILABLE, detail=detail,
                        headers={"Retry-After": str(state.settings.retry_after_s)})


_bearer = HTTPBearer(auto_error=False, description="Needed only when the server sets T2M_API_KEY.")


def require_api_key(state: ServiceState = Depends(get_state),
                    credentials: HTTPAuthorizationCredentials | None = Depends(_bearer)) -> None:
    """401 unless the request carries 'Authorization: Bearer <T2M_API_KEY>' (compared in constant time)."""
    key = state.settings.api_key
    if key is None:
        return
    given = credentials.credentials if credentials is not None else ""
    if not secrets.compare_digest(given.encode(), key.get_secret_value().encode()):
        raise HTTPException(status.HTTP_401_UNAUTHORIZED,
                            detail="missing or wrong API key (send 'Authorization: Bearer <key>')",
                            headers={"WWW-Authenticate": "Bearer"})
