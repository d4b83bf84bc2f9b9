"""Start `t2m serve` on a free loopback port for a benchmark or a test, and stop it afterwards.

Benchmarks and client tests measure the service the way users run it: a separate uvicorn process started by the
CLI, reached over real TCP. This module is that one way of starting it, so every figure comes from the same setup.
"""
from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from urllib.error import HTTPError, URLError
from urllib.parse import urlsplit
from urllib.request import urlopen

import t2m

__all__ = ["LiveServer", "free_port", "require_loopback", "running_server", "wait_until_healthy"]

REPO = Path(t2m.__file__).resolve().parents[1]   # the folder whose `t2m` a child process runs


def require_loopback(url: str) -> None:
    """Refuses any URL whose host is not this machine: these tools generate load and must not aim it elsewhere."""
    parts = urlsplit(url)
    if parts.scheme not in ("http", "https") or parts.hostname not in ("127.0.0.1", "localhost", "::1"):
        raise ValueError(f"url {url!r}: only http(s)://127.0.0.1, localhost or [::1] is allowed (loopback only)")


@dataclass(frozen=True)
class LiveServer:
    url: str
    pid: int
    log_path: Path


def free_port() -> int:
    """A TCP port free right now on 127.0.0.1 (the OS picks it)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def wait_until_healthy(url: str, timeout_s: float, process: subprocess.Popen | None = None,
                       log_path: Path | None = None) -> None:
    """Polls GET /health until 200; fails early with the server's log tail if the process dies."""
    deadline = time.monotonic() + timeout_s
    last = "no answer"
    while time.monotonic() < deadline:
        if process is not None and process.poll() is not None:
            tail = log_path.read_text(errors="replace")[-2000:] if log_path else ""
            raise RuntimeError(f"server exited with code {process.returncode} before it was healthy:\n{tail}")
        try:
            with urlopen(f"{url}/health", timeout=2) as response:
                if response.status == 200:
                    return
                last = f"HTTP {response.status}"
        except HTTPError as error:
            last = f"HTTP {error.code}"
        except (URLError, ConnectionError, TimeoutError, OSError) as error:
            last = str(error)
        time.sleep(0.2)
    raise TimeoutError(f"{url}/health not 200 after {timeout_s:g} s (last: {last})")


@contextlib.contextmanager
def running_server(model_dir: str | Path, env: dict[str, str] | None = None, startup_timeout_s: float = 120.0,
                   log_dir: str | Path | None = None,
                   extra_models: Sequence[str | Path] = (), code_dir: str | Path | None = None) -> Iterator[LiveServer]:
    """`t2m serve --host 127.0.0.1 --port <free> --model DIR` as a child process, healthy on entry, stopped on exit.

    `env` adds T2M_* settings (for example {"T2M_MAX_QUEUE": "2"}); `extra_models` are served next to DIR (one more
    `--model` each; DIR stays the default). The server's output goes to a log file whose tail is shown if it fails
    to start. `code_dir`: another checkout of this repository whose code the server runs (a before/after benchmark
    against an older commit: `git worktree add DIR COMMIT`); default this one.
    """
    code = Path(code_dir).resolve() if code_dir else REPO
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    log_dir = Path(log_dir) if log_dir else Path(tempfile.mkdtemp(prefix="t2m-server-"))
    log_dir.mkdir(parents=True, exist_ok=True)
    log_path = log_dir / f"server-{port}.log"
    child_env = {**os.environ, **(env or {})}
    child_env["PYTHONPATH"] = str(code) if code_dir else child_env.get("PYTHONPATH", str(REPO))
    command = [sys.executable, "-m", "t2m.cli", "serve", "--host", "127.0.0.1", "--port", str(port),
               "--model", str(model_dir)]
    for extra in extra_models:
        command += ["--model", str(extra)]
    with open(log_path, "wb") as log:
        process = subprocess.Popen(command, cwd=code, env=child_env, stdout=log, stderr=subprocess.STDOUT)
    try:
        wait_until_healthy(url, startup_timeout_s, process, log_path)
        yield LiveServer(url=url, pid=process.pid, log_path=log_path)
    finally:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)  # uvicorn's graceful shutdown
            try:
                process.wait(timeout=15)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait(timeout=5)
