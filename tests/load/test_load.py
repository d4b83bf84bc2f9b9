"""A short load test against a real `t2m serve` (uvicorn, tiny random bundle) on loopback.

Normal load must give successes and no 5xx; overload (far more clients than T2M_MAX_QUEUE) must give 429s, no 5xx
and no dropped connections; afterwards the server must answer a normal request; its memory must stay put.
The full figures come from benchmarks/load_test.py; this test only checks the behaviour.
"""
from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from benchmarks.load_test import format_report, run_load
from t2m.testing.server_process import running_server

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def tiny_bundle(tmp_path_factory) -> Path:
    torch = pytest.importorskip("torch")
    torch.set_num_threads(1)
    from t2m.families.gpt.random_bundle import build_random_bundle

    return build_random_bundle(tmp_path_factory.mktemp("bundle") / "tiny")


def test_load_overload_and_recovery(tiny_bundle, tmp_path):
    with running_server(tiny_bundle, env={"T2M_MAX_QUEUE": "2"}, log_dir=tmp_path) as server:
        report = asyncio.run(run_load(server.url, clients=4, seconds=10, server_pid=server.pid,
                                      overload_clients=32, overload_seconds=4, segment_seconds=2.0))
    print(format_report(report, server.url))
    normal, overload = report.phases

    assert normal.status_2xx > 0
    assert normal.status_5xx == 0 and normal.connection_errors == 0 and normal.status_4xx == 0
    assert overload.status_429 > 0, "overload produced no 429"
    assert overload.status_5xx == 0 and overload.connection_errors == 0 and overload.status_4xx == 0
    assert report.recovered, report.recovery_detail

    rss_mb = report.memory.mb()
    assert len(rss_mb) >= 10, "server memory was not sampled"
    assert rss_mb[-1] - rss_mb[0] < 150, f"server RSS grew from {rss_mb[0]:.0f} to {rss_mb[-1]:.0f} MB"
