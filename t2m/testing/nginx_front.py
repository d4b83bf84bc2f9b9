"""Real nginx with the project's own deploy/nginx.conf in front of replicas on loopback ports.

The compose topology names its replicas `t2m:8000` and listens on port 80; here the same file is rendered with the
replica lines, the listen line, the log paths and the temp paths rewritten, and nothing else, so that what is
measured (balancing, retries, timeouts) is the configuration operators deploy. Each rewrite must find its line:
a changed nginx.conf fails loudly instead of being measured half-rendered.
"""
from __future__ import annotations

import contextlib
import os
import re
import shutil
import signal
import socket
import subprocess
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

__all__ = ["NGINX_CONF", "NginxFront", "UpstreamLine", "read_access_log", "render_loopback_config", "running_nginx"]

NGINX_CONF = Path(__file__).resolve().parents[2] / "deploy" / "nginx.conf"   # a checkout's
_REPLICA_LINE = re.compile(r"^(\s*)server t2m:8000\b([^;]*);", re.MULTILINE)
_LOG_FIELD = re.compile(r'"(?P<request>[^"]*)" (?P<status>\d{3}) .*?upstream=(?P<addr>.*?) '
                        r"upstream_status=(?P<ustatus>.*?) upstream_rt=")


def _substitute(pattern: str, replacement: str, text: str, flags: int = re.MULTILINE) -> str:
    new, count = re.subn(pattern, replacement, text, count=1, flags=flags)
    if count != 1:
        raise ValueError(f"deploy/nginx.conf: no line matches {pattern!r}; update t2m/testing/nginx_front.py")
    return new


def render_loopback_config(replica_ports: Sequence[int], listen_port: int, workdir: Path,
                           source: str | None = None) -> str:
    """deploy/nginx.conf with `server t2m:8000 ...;` repeated for 127.0.0.1:<port> of each replica (same
    parameters), `listen 127.0.0.1:<listen_port>`, logs and temp files under `workdir`."""
    if not replica_ports:
        raise ValueError("at least one replica port is needed")
    text = NGINX_CONF.read_text() if source is None else source
    match = _REPLICA_LINE.search(text)
    if match is None:
        raise ValueError("deploy/nginx.conf: no `server t2m:8000 ...;` line; update t2m/testing/nginx_front.py")
    indent, parameters = match.group(1), match.group(2)
    servers = "\n".join(f"{indent}server 127.0.0.1:{port}{parameters};" for port in replica_ports)
    text = text[:match.start()] + servers + text[match.end():]
    text = _substitute(r"^(\s*)listen 80;", rf"\1listen 127.0.0.1:{listen_port};", text)
    text = _substitute(r"access_log /dev/stdout", f"access_log {workdir}/access.log", text)
    text = _substitute(r"error_log /dev/stderr", f"error_log {workdir}/error.log", text)
    temp = "".join(f"\n    {kind}_temp_path {workdir}/{kind}_temp;"
                   for kind in ("client_body", "proxy", "fastcgi", "uwsgi", "scgi"))
    return _substitute(r"^http \{", "http {" + temp, text)


@dataclass(frozen=True)
class UpstreamLine:
    """One access-log line: the client's status and every replica the request was tried on, in order."""
    request: str
    status: int
    upstreams: tuple[str, ...]
    upstream_statuses: tuple[str, ...]

    @property
    def retried(self) -> bool:
        return len(self.upstreams) > 1


def read_access_log(path: Path) -> list[UpstreamLine]:
    """The `upstreams` log format's lines (deploy/nginx.conf); other lines are skipped."""
    lines = []
    for line in path.read_text(errors="replace").splitlines() if path.exists() else []:
        match = _LOG_FIELD.search(line)
        if match is None:
            continue
        # "a, b : c" - nginx separates retries by ", " and internal redirects by " : "
        addresses = tuple(a.strip() for a in re.split(r"[,:]\s", match.group("addr")) if a.strip())
        statuses = tuple(s.strip() for s in re.split(r"[,:]\s", match.group("ustatus")) if s.strip())
        lines.append(UpstreamLine(match.group("request"), int(match.group("status")), addresses, statuses))
    return lines


@dataclass
class NginxFront:
    url: str
    workdir: Path
    process: subprocess.Popen

    @property
    def access_log(self) -> Path:
        return self.workdir / "access.log"

    def set_replicas(self, replica_ports: Sequence[int]) -> None:
        """Re-render for other replicas and reload (SIGHUP: new workers, in-flight requests finish on the old)."""
        port = int(self.url.rsplit(":", 1)[1])
        (self.workdir / "nginx.conf").write_text(render_loopback_config(replica_ports, port, self.workdir))
        self.process.send_signal(signal.SIGHUP)


def _wait_for_port(port: int, process: subprocess.Popen, workdir: Path, timeout_s: float = 30.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if process.poll() is not None:
            error_log = workdir / "error.log"
            tail = error_log.read_text(errors="replace")[-2000:] if error_log.exists() else ""
            raise RuntimeError(f"nginx exited with code {process.returncode}:\n{tail}")
        with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), timeout=1):
            return
        time.sleep(0.1)
    raise TimeoutError(f"nginx is not listening on 127.0.0.1:{port} after {timeout_s:g} s")


@contextlib.contextmanager
def running_nginx(replica_ports: Sequence[int], listen_port: int, workdir: Path,
                  nginx: str | None = None) -> Iterator[NginxFront]:
    """nginx in the foreground (a child process) on 127.0.0.1:listen_port; stopped gracefully (SIGQUIT) on exit."""
    binary = nginx or shutil.which("nginx") or "/usr/sbin/nginx"
    workdir.mkdir(parents=True, exist_ok=True)
    os.chmod(workdir, 0o755)  # nginx's workers run as an unprivileged user when the master is root
    conf = workdir / "nginx.conf"
    conf.write_text(render_loopback_config(replica_ports, listen_port, workdir))
    command = [binary, "-p", str(workdir), "-c", str(conf), "-g", f"daemon off; pid {workdir}/nginx.pid;"]
    with open(workdir / "stderr.log", "wb") as stderr:
        process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=stderr,
                                   preexec_fn=lambda: os.nice(19))
    try:
        _wait_for_port(listen_port, process, workdir)
        yield NginxFront(url=f"http://127.0.0.1:{listen_port}", workdir=workdir, process=process)
    finally:
        if process.poll() is None:
            process.send_signal(signal.SIGQUIT)
            try:
                process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait(timeout=5)
