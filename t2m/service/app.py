"""The FastAPI application factory.

`create_app(settings)` wires settings, middleware (metrics, CORS, body limit), routes and error handlers. The model
bundles (settings.bundle_path, the default, then settings.extra_model_dirs) load in a background thread started by
the lifespan, so /health answers 503 during the load instead of the port staying closed; `engine_factory(settings)`
is called once per bundle (with settings naming that bundle alone) and lets tests inject engines.
"""
from __future__ import annotations

import gc
import logging
import threading
import time
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import FastAPI, Request
from fastapi.exception_handlers import http_exception_handler
from fastapi.exceptions import RequestValidationError
from fastapi.middleware.cors import CORSMiddleware
from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles
from starlette.exceptions import HTTPException as StarletteHTTPException

from t2m import __version__
from t2m.runtime.formats import preload as preload_formats
from t2m.runtime.scheduling import QueuedWorkers, batcher_for
from t2m.runtime.served_models import ModelRegistry, ServedModel, load_engines
from t2m.runtime.step_order import step_order
from t2m.runtime.types import Engine
from t2m.service.dependencies import ServiceState
from t2m.service.metrics import MetricsMiddleware, ServiceMetrics
from t2m.service.middleware import BodySizeLimitMiddleware
from t2m.service.routes import edit, generate, health, metrics
from t2m.service.safe_json import json_safe
from t2m.service.settings import Settings

__all__ = ["app_from_env", "create_app", "load_onnx_engine"]

log = logging.getLogger("service")

STATIC_DIR = Path(__file__).resolve().parent / "static"


def load_onnx_engine(settings: Settings) -> Engine:
    """The production engine: the bundle at settings.bundle_path on onnxruntime."""
    from t2m.runtime.engine import OnnxEngine

    return OnnxEngine.load(settings.bundle_path, check_hashes=settings.verify_hashes,
                           intra_op_threads=settings.intra_op_threads, inter_op_threads=settings.inter_op_threads,
                           unknown_text=settings.unknown_text, stream_every=settings.stream_every_tokens,
                           execution=settings.execution)


def limit_blas_threads(threads: int) -> None:
    """Every BLAS loaded in this process (numpy's, scipy's OpenBLAS or MKL) to `threads` threads (0: leave their own
    choice)."""
    if threads > 0:
        from threadpoolctl import threadpool_limits

        threadpool_limits(limits=threads, user_api="blas")


def freeze_loaded_objects() -> int:
    """Collect once, then move every object still alive (the loaded models' Python side, tokenizers, the app and
    its libraries) to the collector's permanent generation (gc.freeze): those live as long as the process, and the
    decoding loops' many small allocations then trigger collections that walk only requests' objects. Returns how
    many objects were frozen."""
    gc.collect()
    gc.freeze()
    return gc.get_freeze_count()


def _load_in_background(state: ServiceState, factory: Callable[[Settings], Engine]) -> None:
    """Every bundle (the default first), each through `factory` with settings naming it alone, then its batcher."""
    settings = state.settings
    started = time.perf_counter()
    try:
        loaded = load_engines(settings.model_dirs, lambda directory: factory(settings.for_bundle(directory)))
        preload_formats()
        limit_blas_threads(settings.blas_threads)     # after the loads: they bring further BLAS libraries (scipy's)
        if settings.gc_freeze:
            log.info("%d objects frozen out of the garbage collector's generations", freeze_loaded_objects())
    except Exception as error:  # reported by /health; the process stays up so the cause is visible
        log.error("model bundles failed to load: %s", error)
        state.set_error(str(error))
        return
    models = ModelRegistry([
        ServedModel(item.directory, item.engine, _batcher_for(item.engine, settings), item.load_seconds)
        for item in loaded])
    state.set_ready(models, time.perf_counter() - started)
    for model in models:
        log.info("model %s %s ready (%s)%s", model.name, model.limits.version, model.directory,
                 " - the default" if model is models.default else "")
    log.info("%d model(s) ready in %.1f s", len(models), state.load_seconds)


def _batcher_for(engine: Engine, settings: Settings) -> QueuedWorkers:
    return batcher_for(engine, continuous=settings.continuous_batching, max_queue=settings.max_queue,
                       max_batch_rows=settings.max_batch_rows, window_s=settings.batch_window_ms / 1000.0,
                       workers=settings.engine_workers,
                       step_order=step_order(settings.step_order, settings.max_step_skips))


def create_app(settings: Settings | None = None, *,
               engine_factory: Callable[[Settings], Engine] | None = None) -> FastAPI:
    """A new app instance with its own state and metrics registry."""
    settings = settings or Settings()
    factory = engine_factory or load_onnx_engine
    state = ServiceState(settings=settings, metrics=ServiceMetrics())

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        loader = threading.Thread(target=_load_in_background, args=(state, factory), name="t2m-load", daemon=True)
        loader.start()
        try:
            yield
        finally:
            if state.models is not None:
                state.models.close()

    app = FastAPI(title="t2m-service", version=__version__, lifespan=lifespan,
                  description="Text to 3D human motion: a stream of sentences with durations becomes one continuous "
                              "motion (22-joint SMPL skeleton, 20 fps) as JSON joints, BVH or glTF binary.")
    app.state.service = state
    app.include_router(generate.router)
    app.include_router(edit.router)
    app.include_router(health.router)
    app.include_router(metrics.router)
    _add_viewer(app)

    @app.exception_handler(RequestValidationError)
    async def invalid_request(request: Request, error: RequestValidationError) -> JSONResponse:
        """FastAPI's 422 shape (detail = [{loc, msg, type, ...}]); the echoed input made safe (NaN, lone
        surrogates, bytes that are no UTF-8, deep nesting) so that the answer is a 422, never a 500."""
        return JSONResponse({"detail": json_safe(error.errors())}, status_code=422)

    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, error: StarletteHTTPException) -> Response:
        """FastAPI's answer to an HTTPException (401, 404, 413, 429, ...), its detail made safe the same way."""
        safe = StarletteHTTPException(error.status_code, json_safe(error.detail), getattr(error, "headers", None))
        return await http_exception_handler(request, safe)

    @app.exception_handler(Exception)
    async def internal_error(request: Request, error: Exception) -> JSONResponse:
        """Never a traceback to the client; the log has it."""
        log.error("internal error on %s %s", request.method, request.url.path, exc_info=error)
        return JSONResponse({"detail": "internal server error"}, status_code=500)

    # added last = outermost: metrics see every answer, including 413 and CORS pre-flights
    app.add_middleware(BodySizeLimitMiddleware, max_bytes=settings.max_body_bytes)
    if settings.cors_origins:
        app.add_middleware(CORSMiddleware, allow_origins=settings.cors_origins, allow_methods=["GET", "POST"],
                           allow_headers=["Authorization", "Content-Type"],
                           expose_headers=["X-Seed", "X-T2M-Warnings", "Content-Disposition", "Retry-After"])
    known = _route_paths(app)
    app.add_middleware(MetricsMiddleware, metrics=state.metrics, known_paths=lambda: known)
    return app


def _route_paths(app: FastAPI) -> set[str]:
    """The path templates the app serves (metric labels); included routers are looked into."""
    paths: set[str] = set()
    for route in app.routes:
        path = getattr(route, "path", None)
        if path:
            paths.add(path)
        included = getattr(route, "original_router", None)
        paths.update(getattr(sub, "path", "") for sub in getattr(included, "routes", []))
    return paths - {""}


def _add_viewer(app: FastAPI) -> None:
    """The browser viewer at / (service/static), when it is installed."""
    index = STATIC_DIR / "index.html"
    if not index.is_file():
        return
    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")

    @app.get("/", include_in_schema=False)
    def viewer() -> FileResponse:
        return FileResponse(index)


def app_from_env() -> FastAPI:
    """For `uvicorn --factory t2m.service.app:app_from_env` (several workers): settings from T2M_* variables."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    return create_app(Settings())
