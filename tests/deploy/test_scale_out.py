"""The scale-out topology run for real (`-m deploy`): replicas behind nginx with deploy/nginx.conf on loopback, one
killed mid-request, one stopped mid-request. Replicas are containers of $T2M_DEPLOY_IMAGE (host network) when it is
set (.ci/run sets it after scripts/docker_smoke.sh built the image), else `t2m serve` processes.

The rendering of nginx.conf for loopback is checked in the default suite (it needs no nginx)."""
from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx
import pytest

from t2m.service.settings import Settings
from t2m.testing.nginx_front import NGINX_CONF, NginxFront, read_access_log, render_loopback_config, running_nginx
from t2m.testing.replicas import Replica, make_replicas
from t2m.testing.server_process import free_port

# two sentences of 4 s: long enough to be caught in flight on a busy machine, short enough for CI
BODY = {"segments": [{"text": "a person walks forward", "duration": 4.0},
                     {"text": "a person waves with the right hand", "duration": 4.0}], "seed": 5}
FRAMES = 2 * 80


def test_rendered_config_keeps_everything_but_addresses_and_paths(tmp_path):
    text = render_loopback_config([41001, 41002], 41000, tmp_path)
    source = NGINX_CONF.read_text()
    parameters = re.search(r"server t2m:8000\b([^;]*);", source).group(1)
    assert re.findall(r"server (\S+?)(?: [^;]*)?;", text) == ["127.0.0.1:41001", "127.0.0.1:41002"]
    assert text.count(parameters + ";") == 2
    assert "listen 127.0.0.1:41000;" in text and "listen 80;" not in text
    assert "/dev/std" not in text and f"access_log {tmp_path}/access.log upstreams;" in text
    for directive in ("proxy_next_upstream ", "proxy_next_upstream_tries", "proxy_next_upstream_timeout",
                      "least_conn", "proxy_read_timeout", "client_max_body_size"):
        (line,) = [line for line in source.splitlines() if line.strip().startswith(directive)]
        assert line in text.splitlines()


def test_rendering_refuses_a_config_it_does_not_recognise(tmp_path):
    with pytest.raises(ValueError, match="server t2m:8000"):
        render_loopback_config([1], 2, tmp_path, source=NGINX_CONF.read_text().replace("t2m:8000", "api:9000"))
    with pytest.raises(ValueError, match="listen 80"):
        render_loopback_config([1], 2, tmp_path, source=NGINX_CONF.read_text().replace("listen 80;", "listen 81;"))


def test_access_log_lines_name_every_replica_tried(tmp_path):
    log = tmp_path / "access.log"
    log.write_text(
        '127.0.0.1 [25/Nov/2026:10:00:00 +0000] "POST /generate HTTP/1.1" 200 99 rt=1.2 '
        'upstream=127.0.0.1:1, 127.0.0.1:2 upstream_status=502, 200 upstream_rt=0.5, 0.7 rid=ab\n'
        '127.0.0.1 [25/Nov/2026:10:00:01 +0000] "GET /health HTTP/1.1" 200 9 rt=0.0 '
        'upstream=127.0.0.1:2 upstream_status=200 upstream_rt=0.001 rid=cd\n'
        'not a log line\n')
    first, second = read_access_log(log)
    assert first.retried and first.upstreams == ("127.0.0.1:1", "127.0.0.1:2") and first.upstream_statuses == (
        "502", "200") and first.status == 200
    assert not second.retried and second.request == "GET /health HTTP/1.1"


def test_retry_window_outlasts_a_generation():
    """nginx hands on a request whose replica died at any point of a generation the replica could still finish."""
    text = NGINX_CONF.read_text()
    window = int(re.search(r"proxy_next_upstream_timeout (\d+)s;", text).group(1))
    assert window > Settings().request_timeout_s
    assert re.search(r"proxy_next_upstream [^;]*\berror\b[^;]*\bnon_idempotent\b", text)


# ---- live: real nginx and real replicas ------------------------------------------------------------------------

def _need_nginx() -> str:
    nginx = shutil.which("nginx") or ("/usr/sbin/nginx" if Path("/usr/sbin/nginx").exists() else None)
    if nginx is None:
        pytest.skip("nginx is not installed (apt-get install nginx)")
    return nginx


@pytest.fixture
def replicas(tmp_path) -> Iterator[list[Replica]]:
    image = os.environ.get("T2M_DEPLOY_IMAGE") or None
    if image and subprocess.run(["docker", "image", "inspect", image], capture_output=True).returncode != 0:
        pytest.fail(f"T2M_DEPLOY_IMAGE={image} is not an image here")
    # Each request waits 1.5 s in its replica's batch window before it generates: a kill or stop sent once a replica
    # is seen busy then always lands mid-request (an idle machine generates a motion in ~0.1 s, a race otherwise).
    started = make_replicas(2, tmp_path / "replicas", image=image, env={"T2M_BATCH_WINDOW_MS": "1500",
                                                                                  "T2M_CONTINUOUS_BATCHING": "false"})
    try:
        for replica in started:
            replica.start()
        for replica in started:
            replica.wait_healthy(timeout_s=600)
        yield started
    finally:
        for replica in started:
            replica.remove()


def _in_flight(url: str) -> float:
    """Requests the replica holds: queued (in its batch window) or generating; a kill loses both."""
    text = httpx.get(f"{url}/metrics", timeout=30).text
    pattern = r"^t2m_(?:in_flight|queue_depth)\{[^}]*\} (\S+)$"
    return sum(float(value) for value in re.findall(pattern, text, re.MULTILINE))


def _wait_in_flight(replica: Replica, pending: list) -> None:
    """Until the replica is generating (its t2m_in_flight gauge); fails if every request ended first."""
    while _in_flight(replica.url) < 1:
        if all(future.done() for future in pending):
            outcomes = [f.exception() or f.result().status_code for f in pending]
            raise AssertionError(f"every request ended before the replica was caught busy: {outcomes}")
        time.sleep(0.1)


def _generate(url: str) -> httpx.Response:
    return httpx.post(f"{url}/generate", json=BODY, timeout=600)


@pytest.mark.deploy
def test_replica_killed_mid_request_fails_no_request_and_rejoins(replicas, tmp_path):
    _need_nginx()
    killed = replicas[0]
    with running_nginx([r.port for r in replicas], free_port(), tmp_path / "nginx") as front, \
            ThreadPoolExecutor(4) as pool:
        pending = [pool.submit(_generate, front.url) for _ in range(4)]  # least_conn: 2 on each replica
        _wait_in_flight(killed, pending)
        killed.signal(signal.SIGKILL)
        responses = [future.result() for future in pending]
        assert [r.status_code for r in responses] == [200] * 4, [r.text[:200] for r in responses]
        assert all(len(r.json()["frames"]) == FRAMES for r in responses)
        lines = [line for line in read_access_log(front.access_log) if "/generate" in line.request]
        handed_on = [line for line in lines if line.retried and line.upstreams[0] == f"127.0.0.1:{killed.port}"]
        assert handed_on and all(line.status == 200 for line in handed_on), lines

        assert killed.wait_exit(60) != 0
        killed.start()  # what docker's restart policy or Kubernetes does
        killed.wait_healthy(timeout_s=600)
        _assert_rejoins(front, killed)


def _assert_rejoins(front: NginxFront, replica: Replica, attempts: int = 30) -> None:
    """nginx sends the restarted replica requests again (after its fail_timeout if it had been marked down)."""
    address = f"127.0.0.1:{replica.port}"
    for _ in range(attempts):
        before = len(read_access_log(front.access_log))
        assert httpx.get(f"{front.url}/health", timeout=30).status_code == 200
        line = _next_log_line(front, before)
        if line.upstreams[-1] == address:
            return
        time.sleep(1.0)
    pytest.fail(f"nginx sent none of {attempts} requests to the restarted replica {address}")


def _next_log_line(front: NginxFront, before: int, timeout_s: float = 10.0):
    """The access-log line after the first `before` ones: nginx writes it once the answer is sent, which can be just
    after the client has read it."""
    deadline = time.perf_counter() + timeout_s
    while True:
        lines = read_access_log(front.access_log)[before:]
        if lines or time.perf_counter() > deadline:
            (line,) = lines
            return line
        time.sleep(0.05)


@pytest.mark.deploy
def test_sigterm_finishes_in_flight_requests_then_exits(replicas):
    replica = replicas[1]
    with ThreadPoolExecutor(2) as pool:
        pending = [pool.submit(_generate, replica.url) for _ in range(2)]
        _wait_in_flight(replica, pending)
        replica.signal(signal.SIGTERM)
        responses = [future.result() for future in pending]
    assert [r.status_code for r in responses] == [200, 200], [r.text[:200] for r in responses]
    assert all(len(r.json()["frames"]) == FRAMES for r in responses)
    # uvicorn ends by re-raising the signal it handled: a process dies of it (-15; as a container's PID 1, where the
    # kernel ignores it, the exit code is 0), after the complete shutdown its log reports
    assert replica.wait_exit(120) in (0, -signal.SIGTERM, 128 + signal.SIGTERM)
    assert "Application shutdown complete." in replica.logs()
    with pytest.raises(httpx.ConnectError):  # and it accepts nothing more
        httpx.get(f"{replica.url}/health", timeout=10)
