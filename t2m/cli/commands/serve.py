"""`t2m serve`: run the HTTP service (uvicorn on service.app) - the same command the container runs."""
from __future__ import annotations

import argparse
import os
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "serve", help="run the HTTP API (POST /generate, GET /health, GET /metrics)",
        description="Serve the model over HTTP. Every T2M_* environment variable of service/settings.py applies "
                    "(T2M_MAX_QUEUE, T2M_REQUEST_TIMEOUT_S, T2M_API_KEY, T2M_CORS_ORIGINS, ...).")
    parser.add_argument("--host", default="127.0.0.1", help="interface to listen on (default 127.0.0.1)")
    parser.add_argument("--port", type=int, default=8000, help="TCP port (default 8000)")
    parser.add_argument("--model", type=Path, default=None,
                        help="model bundle directory (default: T2M_MODEL_DIR, else the embedded t2m/bundles/default)")
    parser.add_argument("--workers", type=int, default=1,
                        help="uvicorn worker processes, each with its own model copy and /metrics (default 1)")
    parser.add_argument("--log-level", default="info", choices=("critical", "error", "warning", "info", "debug"))
    parser.set_defaults(func=_serve)


def _serve(args: argparse.Namespace) -> int:
    import uvicorn

    from t2m.bundle import read_manifest
    from t2m.cli.main import CliError
    from t2m.service.settings import Settings

    if not 1 <= args.port <= 65535:
        raise CliError(f"--port must be 1..65535, got {args.port}")
    if args.workers < 1:
        raise CliError(f"--workers must be at least 1, got {args.workers}")
    if args.model is not None:
        # the environment carries the choice into every worker process (settings read T2M_BUNDLE_PATH first)
        os.environ["T2M_BUNDLE_PATH"] = str(args.model.resolve())
    bundle = Settings().bundle_path
    read_manifest(bundle)   # fail now, in one line, if the directory is no bundle; hashes are checked by the server
    uvicorn.run("t2m.service.app:app_from_env", factory=True, host=args.host, port=args.port, workers=args.workers,
                log_level=args.log_level, proxy_headers=True, forwarded_allow_ips="*")
    return 0
