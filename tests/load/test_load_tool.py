"""The load tools refuse non-loopback targets and unbounded runs before sending anything."""
from __future__ import annotations

import asyncio

import pytest

from benchmarks.http_latency import main as latency_main
from benchmarks.load_test import main as load_main
from benchmarks.load_test import run_phase
from benchmarks.step_order import main as step_order_main
from benchmarks.stream_latency import main as stream_main
from t2m.testing.server_process import require_loopback


@pytest.mark.parametrize("url", ["http://127.0.0.1:8000", "http://localhost:1", "http://[::1]:8000/"])
def test_loopback_urls_are_accepted(url):
    require_loopback(url)


@pytest.mark.parametrize("url", ["http://example.com", "http://10.0.0.5:8000", "http://127.0.0.1.nip.io",
                                 "ftp://127.0.0.1", "http://0.0.0.0:8000"])
def test_other_hosts_are_refused(url):
    with pytest.raises(ValueError, match="loopback"):
        require_loopback(url)


def test_cli_refuses_in_one_line(capsys):
    assert load_main(["--url", "http://example.com"]) == 2
    assert load_main(["--url", "http://127.0.0.1:9", "--clients", "100000"]) == 2
    assert load_main(["--url", "http://127.0.0.1:9", "--seconds", "86400"]) == 2
    assert latency_main(["--url", "http://192.168.1.1"]) == 2
    assert latency_main(["--url", "http://127.0.0.1:9", "--formats", "json,fbx"]) == 2
    assert stream_main(["--url", "http://10.0.0.5:8000"]) == 2
    assert stream_main(["--url", "http://127.0.0.1:9", "--repeats", "0"]) == 2
    assert step_order_main(["--before-env", "BLAS=0"]) == 2                  # not a T2M_ setting: refused, no server
    errors = capsys.readouterr().err.strip().splitlines()
    assert len(errors) == 8 and all(": error: " in line for line in errors)
    assert "--before-env: 'BLAS=0' is not T2M_NAME=VALUE" in errors[-1]


def test_run_phase_checks_bounds_before_connecting():
    with pytest.raises(ValueError, match="clients"):
        asyncio.run(run_phase("http://127.0.0.1:9", "x", clients=0, seconds=1))
    with pytest.raises(ValueError, match="loopback"):
        asyncio.run(run_phase("http://example.com", "x", clients=1, seconds=1))
