"""`t2m serve`: run the HTTP service (uvicorn on service.app) - the same command the container runs.

The HTTP service adds this command to the CLI (pyproject's entry point group t2m_commands), so the CLI itself
never imports the service."""
from __future__ import annotations

import argparse
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from t2m.service.settings import Settings

HELP = "run the HTTP service"


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "serve", help="run the HTTP API (POST /generate, GET /health, GET /metrics)",
        description="Serve the model(s) over HTTP. Every T2M_* environment variable of service/settings.py applies "
                    "(T2M_MAX_QUEUE, T2M_REQUEST_TIMEOUT_S, T2M_API_KEY, T2M_CORS_ORIGINS, ...).")
    # the container sets T2M_HOST/T2M_PORT, so that its HEALTHCHECK probes the port the server really listens on
    parser.add_argument("--host", default=os.environ.get("T2M_HOST", "127.0.0.1"),
                        help="interface to listen on (default: T2M_HOST, else 127.0.0.1)")
    parser.add_argument("--port", type=_port, default=os.environ.get("T2M_PORT", "8000"),
                        help="TCP port (default: T2M_PORT, else 8000)")
    parser.add_argument("--model", type=Path, action="append", default=None, metavar="DIR",
                        help="model bundle directory; repeat to serve several (the first is the default, a request "
                             "picks another by its manifest name). Given, it names every model served "
                             "(T2M_EXTRA_MODEL_DIRS is replaced); default: T2M_MODEL_DIR (+ T2M_EXTRA_MODEL_DIRS), "
                             "else the embedded t2m/bundles/default. An embedded bundle can be named by its folder "
                             "name: --model default --model masked")
    parser.add_argument("--providers", default=None, metavar="LIST",
                        help="onnxruntime execution providers of the model sessions, comma-separated: cpu, or cuda "
                             "(CUDA then CPU; needs onnxruntime-gpu, the 'gpu' extra). Sets "
                             "T2M_EXECUTION_PROVIDERS (default: that variable, else cpu)")
    parser.add_argument("--workers", type=int, default=1,
                        help="uvicorn worker processes, each with its own model copies and /metrics (default 1)")
    parser.add_argument("--log-level", default="info", choices=("critical", "error", "warning", "info", "debug"))
    parser.set_defaults(func=_serve)


def _port(text: str) -> int:
    """A TCP port number (also the T2M_PORT default, which argparse converts with this too)."""
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a port number: {text!r}") from None


def model_environment(models: Sequence[Path]) -> dict[str, str]:
    """The T2M_* variables that carry `--model` choices into every worker process: the first bundle is the default
    (T2M_BUNDLE_PATH, which settings read first), the others T2M_EXTRA_MODEL_DIRS (comma-separated)."""
    from t2m.bundles import resolve_bundle
    from t2m.cli.main import CliError

    paths = [str(resolve_bundle(model).resolve()) for model in models]
    for path in paths:
        if "," in path:
            raise CliError(f"--model {path}: a bundle path with a comma cannot be served next to others "
                           "(T2M_EXTRA_MODEL_DIRS is comma-separated); rename the directory")
    return {"T2M_BUNDLE_PATH": paths[0], "T2M_EXTRA_MODEL_DIRS": ",".join(paths[1:])}


def check_bundles(directories: Sequence[Path]) -> None:
    """Fail now, in one line, if a directory is no bundle or two bundles share a manifest name (hashes are checked by
    the server)."""
    from t2m.bundle import read_manifest
    from t2m.cli.main import CliError

    seen: dict[str, Path] = {}
    for directory in directories:
        name = read_manifest(directory).name
        if name in seen:
            raise CliError(f"--model {seen[name]} and {directory} are both named {name!r}: every served model needs "
                           "its own manifest name (a request picks a model by it)")
        seen[name] = directory


def provider_list(text: str) -> str:
    """`--providers` checked (an unknown name: a one-line ProviderError naming the setting), as the env holds it."""
    from t2m.runtime.execution import ort_providers

    names = [item.strip().lower() for item in text.split(",") if item.strip()]
    ort_providers(names)
    if not names:
        raise ValueError("--providers: name at least one provider (cpu, cuda)")
    return ",".join(names)


def check_providers(settings: Settings) -> None:
    """Fail now, in one line naming T2M_EXECUTION_PROVIDERS, if the installed onnxruntime lacks a provider (rather
    than a /health 503 after the server started)."""
    from t2m.runtime.execution import check_available

    check_available(settings.execution_providers)


def graceful_shutdown_seconds(settings: Settings) -> int:
    """How long a stopping server waits for its requests: the request timeout and a few seconds to send the answer."""
    return math.ceil(settings.request_timeout_s) + 5


def _serve(args: argparse.Namespace) -> int:
    import uvicorn

    from t2m.cli.main import CliError
    from t2m.service.request_deadlines import IMPORT_PATH as DEADLINE_PROTOCOL
    from t2m.service.settings import Settings

    if not 1 <= args.port <= 65535:
        raise CliError(f"--port must be 1..65535, got {args.port}")
    if args.workers < 1:
        raise CliError(f"--workers must be at least 1, got {args.workers}")
    if args.model:
        os.environ.update(model_environment(args.model))
    if args.providers is not None:
        os.environ["T2M_EXECUTION_PROVIDERS"] = provider_list(args.providers)
    settings = Settings()
    check_providers(settings)
    check_bundles(settings.model_dirs)
    # SIGTERM (docker stop, Kubernetes): stop accepting, finish the requests in flight, exit. A generation ends
    # within the request timeout (504 after it), so waiting longer than that only delays the exit of a stuck one.
    # http: uvicorn's protocol with deadlines for receiving a request (T2M_HEADER_TIMEOUT_S, T2M_BODY_TIMEOUT_S),
    # named by import path so that every worker process loads it. ws="none": the API has no WebSocket route, so an
    # Upgrade request is an ordinary HTTP request with a JSON answer (not uvicorn's bare 403 handshake refusal).
    # timeout_keep_alive: uvicorn's 5 s equals httpx's own idle expiry, and the two racing dropped a request now and
    # then under load (a client reusing the connection the server was closing: ReadError in the slow load test).
    uvicorn.run("t2m.service.app:app_from_env", factory=True, host=args.host, port=args.port, workers=args.workers,
                log_level=args.log_level, proxy_headers=True, forwarded_allow_ips="*", http=DEADLINE_PROTOCOL,
                ws="none", timeout_keep_alive=settings.keep_alive_s,
                timeout_graceful_shutdown=graceful_shutdown_seconds(settings))
    return 0
