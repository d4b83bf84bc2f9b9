"""Load test of a running t2m service on this machine: throughput, latency percentiles, status counts, server memory.

Three phases, printed as markdown tables:
  normal    N clients send POST /generate back to back for M seconds (a 429 makes a client wait Retry-After, as a
            polite real client would).
  overload  many more clients than the server's queue bound, retrying 429s almost at once: the server must answer
            429 (not 5xx), stay up, and keep its memory.
  recovery  after the overload, GET /health is 200 again and one normal request succeeds.
The server's resident memory is sampled throughout (psutil if installed, else /proc/<pid>/status) to show it is steady.

Only loopback URLs are accepted, and clients, seconds and requests are bounded: this is a benchmark, not a weapon.

    python -m benchmarks.load_test --url http://127.0.0.1:8000 --server-pid 1234 --clients 4 --seconds 10 --overload
    # starts its own server:
    python -m benchmarks.load_test --model t2m/bundles/default --clients 4 --seconds 10 --overload
"""
from __future__ import annotations

import argparse
import asyncio
import json
import random
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import numpy as np

from t2m.bench.phases import SENTENCES, PhaseResult
from t2m.testing.server_process import require_loopback, running_server

__all__ = ["LoadReport", "MemoryTrace", "PhaseResult", "format_report", "main", "rss_bytes", "run_load", "run_phase"]

MAX_CLIENTS = 512
MAX_SECONDS = 600.0
MAX_REQUESTS = 50_000


def rss_bytes(pid: int) -> int | None:
    """Resident set size of a process, or None if it is gone or unreadable."""
    try:
        import psutil  # optional; /proc is enough on Linux
    except ImportError:
        psutil = None
    if psutil is not None:
        try:
            return int(psutil.Process(pid).memory_info().rss)
        except psutil.Error:
            return None
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    except OSError:
        return None
    return None


@dataclass
class MemoryTrace:
    samples: list[tuple[float, int]] = field(default_factory=list)  # (seconds since start, rss bytes)

    def mb(self) -> list[float]:
        return [rss / 2**20 for _, rss in self.samples]


@dataclass
class LoadReport:
    phases: list[PhaseResult]
    memory: MemoryTrace
    recovered: bool | None  # None: no overload phase
    recovery_detail: str = ""

    @property
    def server_errors(self) -> int:
        return sum(p.status_5xx + p.connection_errors for p in self.phases)

    def to_json(self) -> dict:
        return {"phases": [p.summary() for p in self.phases], "recovered": self.recovered,
                "recovery_detail": self.recovery_detail,
                "memory_mb": [(round(t, 2), round(rss / 2**20, 1)) for t, rss in self.memory.samples]}


def request_body(rng: random.Random, segment_seconds: float, segments: int, fmt: str) -> dict:
    return {"segments": [{"text": rng.choice(SENTENCES), "duration": segment_seconds} for _ in range(segments)],
            "format": fmt, "seed": rng.randrange(2**31)}


async def post_and_record(client: httpx.AsyncClient, url: str, body: dict, result: PhaseResult,
                          headers: dict[str, str] | None = None) -> httpx.Response | None:
    """One POST /generate, counted into ``result`` by its outcome (2xx latency, 429, 4xx, 5xx, connection error);
    returns the response, or None after a connection error (it waits 0.1 s first)."""
    started = time.perf_counter()
    try:
        response = await client.post(f"{url}/generate", json=body, headers=headers)
        await response.aread()
    except httpx.HTTPError as error:
        result.connection_errors += 1
        result.error_samples.append(f"{type(error).__name__}: {error}")
        await asyncio.sleep(0.1)
        return None
    status = response.status_code
    if 200 <= status < 300:
        result.status_2xx += 1
        result.latencies_ms.append((time.perf_counter() - started) * 1000.0)
    elif status == 429:
        result.status_429 += 1
    elif status >= 500:
        result.status_5xx += 1
        result.error_samples.append(f"HTTP {status}: {response.text[:200]}")
    else:
        result.status_4xx += 1
        result.error_samples.append(f"HTTP {status}: {response.text[:200]}")
    return response


async def _client_loop(client: httpx.AsyncClient, url: str, result: PhaseResult, deadline: float,
                       budget: list[int], rng: random.Random, body_args: tuple[float, int, str],
                       backoff_on_429: bool, headers: dict[str, str]) -> None:
    """One simulated user: request, record, repeat until the deadline or the shared request budget is spent."""
    while time.monotonic() < deadline and budget[0] > 0:
        budget[0] -= 1
        response = await post_and_record(client, url, request_body(rng, *body_args), result, headers)
        if response is not None and response.status_code == 429:
            retry_after = float(response.headers.get("Retry-After", "1") or 1)
            await asyncio.sleep(min(retry_after, 5.0) if backoff_on_429 else 0.05)


async def run_phase(url: str, name: str, clients: int, seconds: float, *, segment_seconds: float = 3.0,
                    segments: int = 1, fmt: str = "json", backoff_on_429: bool = True, max_requests: int = MAX_REQUESTS,
                    seed: int = 0, api_key: str | None = None, request_timeout_s: float = 120.0) -> PhaseResult:
    """`clients` concurrent users for `seconds` (requests in flight at the deadline are awaited and counted)."""
    require_loopback(url)
    if not 1 <= clients <= MAX_CLIENTS:
        raise ValueError(f"clients: {clients} is outside 1..{MAX_CLIENTS}")
    if not 0 < seconds <= MAX_SECONDS:
        raise ValueError(f"seconds: {seconds} is outside (0, {MAX_SECONDS:g}]")
    result = PhaseResult(name=name, clients=clients, seconds=seconds)
    headers = {"Authorization": f"Bearer {api_key}"} if api_key else {}
    budget = [min(max_requests, MAX_REQUESTS)]
    limits = httpx.Limits(max_connections=clients, max_keepalive_connections=clients)
    async with httpx.AsyncClient(timeout=request_timeout_s, limits=limits) as client:
        started = time.monotonic()
        deadline = started + seconds
        await asyncio.gather(*(
            _client_loop(client, url, result, deadline, budget, random.Random(seed * 1000 + i),
                         (segment_seconds, segments, fmt), backoff_on_429, headers)
            for i in range(clients)))
        result.seconds = time.monotonic() - started
    return result


async def _sample_memory(pid: int, trace: MemoryTrace, stop: asyncio.Event, every_s: float) -> None:
    start = time.monotonic()
    while True:
        rss = rss_bytes(pid)
        if rss is not None:
            trace.samples.append((time.monotonic() - start, rss))
        try:
            await asyncio.wait_for(stop.wait(), timeout=every_s)
            return
        except asyncio.TimeoutError:
            pass


async def _recover(url: str, timeout_s: float, api_key: str | None) -> tuple[bool, str]:
    """After overload: wait for /health 200, then one ordinary request must succeed."""
    headers = {"Authorization": f"Bearer {api_key}"} if api_key else {}
    deadline = time.monotonic() + timeout_s
    last = ""
    async with httpx.AsyncClient(timeout=120.0) as client:
        while time.monotonic() < deadline:
            try:
                health = await client.get(f"{url}/health")
                if health.status_code == 200:
                    body = request_body(random.Random(7), 2.0, 1, "json")
                    response = await client.post(f"{url}/generate", json=body, headers=headers)
                    if response.status_code == 200:
                        return True, f"200 after overload; {len(response.json()['frames'])} frames"
                    last = f"POST /generate -> {response.status_code}"
                else:
                    last = f"GET /health -> {health.status_code}"
            except httpx.HTTPError as error:
                last = f"{type(error).__name__}: {error}"
            await asyncio.sleep(0.5)
    return False, f"no successful request within {timeout_s:g} s (last: {last})"


async def run_load(url: str, *, clients: int, seconds: float, server_pid: int | None = None,
                   overload_clients: int = 0, overload_seconds: float = 5.0, segment_seconds: float = 3.0,
                   fmt: str = "json", api_key: str | None = None, memory_every_s: float = 0.5,
                   recovery_timeout_s: float = 60.0) -> LoadReport:
    """The normal phase, then (if overload_clients > 0) the overload and recovery phases, memory sampled throughout."""
    require_loopback(url)
    trace = MemoryTrace()
    stop = asyncio.Event()
    sampler = asyncio.create_task(_sample_memory(server_pid, trace, stop, memory_every_s)) if server_pid else None
    phases = [await run_phase(url, "normal", clients, seconds, segment_seconds=segment_seconds, fmt=fmt,
                              api_key=api_key)]
    recovered, detail = None, ""
    if overload_clients > 0:
        phases.append(await run_phase(url, "overload", overload_clients, overload_seconds,
                                      segment_seconds=segment_seconds, fmt=fmt, backoff_on_429=False,
                                      api_key=api_key, seed=1))
        recovered, detail = await _recover(url, recovery_timeout_s, api_key)
    stop.set()
    if sampler:
        await sampler
    return LoadReport(phases=phases, memory=trace, recovered=recovered, recovery_detail=detail)


def _ms(value: float | None) -> str:
    return "-" if value is None else f"{value:.0f}"


def format_report(report: LoadReport, url: str) -> str:
    """Markdown tables: one row per phase, then memory over time."""
    lines = [f"### Load test against {url}", "",
             "| phase | clients | s | requests | ok/s | p50 ms | p95 ms | p99 ms | 2xx | 4xx | 429 | 5xx | conn err |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for phase in report.phases:
        s = phase.summary()
        lines.append(f"| {s['phase']} | {s['clients']} | {s['seconds']:.1f} | {s['requests']} | {s['ok_per_s']:.2f} | "
                     f"{_ms(s['p50_ms'])} | {_ms(s['p95_ms'])} | {_ms(s['p99_ms'])} | {s['2xx']} | {s['4xx']} | "
                     f"{s['429']} | {s['5xx']} | {s['connection_errors']} |")
    if report.recovered is not None:
        lines += ["", f"Recovery after overload: {'OK' if report.recovered else 'FAILED'} ({report.recovery_detail})"]
    samples = report.memory.samples
    if samples:
        mb = report.memory.mb()
        picks = sorted(set(np.linspace(0, len(samples) - 1, num=min(len(samples), 8)).round().astype(int)))
        lines += ["", f"Server RSS (MB) over time: start {mb[0]:.1f}, peak {max(mb):.1f}, end {mb[-1]:.1f} "
                      f"(end - start {mb[-1] - mb[0]:+.1f})", "",
                  "| t (s) | " + " | ".join(f"{samples[i][0]:.0f}" for i in picks) + " |",
                  "| --- | " + " | ".join("---:" for _ in picks) + " |",
                  "| RSS MB | " + " | ".join(f"{mb[i]:.0f}" for i in picks) + " |"]
    errors = [e for p in report.phases for e in p.error_samples[:3]]
    if errors:
        lines += ["", "Sample errors:"] + [f"- {e}" for e in errors]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    target = parser.add_mutually_exclusive_group(required=True)
    target.add_argument("--url", help="a running service on loopback, e.g. http://127.0.0.1:8000")
    target.add_argument("--model", help="start `t2m serve` on this bundle on a free loopback port and test that")
    parser.add_argument("--server-pid", type=int, help="pid of the server (for memory); implied with --model")
    parser.add_argument("--clients", type=int, default=4)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--segment-seconds", type=float, default=3.0, help="duration of each request's motion")
    parser.add_argument("--format", default="json", choices=["json", "bvh", "glb"])
    parser.add_argument("--overload", action="store_true", help="also run the overload and recovery phases")
    parser.add_argument("--overload-clients", type=int, default=64)
    parser.add_argument("--overload-seconds", type=float, default=5.0)
    parser.add_argument("--max-queue", type=int, help="with --model: the server's T2M_MAX_QUEUE")
    parser.add_argument("--api-key", help="bearer token if the server needs one")
    parser.add_argument("--json-out", help="also write the figures as JSON here")
    args = parser.parse_args(argv)

    try:
        for name, value, limit in (("--clients", args.clients, MAX_CLIENTS),
                                   ("--overload-clients", args.overload_clients, MAX_CLIENTS)):
            if not 1 <= value <= limit:
                raise ValueError(f"{name}: {value} is outside 1..{limit}")
        for name, value in (("--seconds", args.seconds), ("--overload-seconds", args.overload_seconds)):
            if not 0 < value <= MAX_SECONDS:
                raise ValueError(f"{name}: {value} is outside (0, {MAX_SECONDS:g}]")
        if args.url:
            require_loopback(args.url)
    except ValueError as error:
        print(f"load_test: error: {error}", file=sys.stderr)
        return 2

    def run(url: str, pid: int | None) -> LoadReport:
        return asyncio.run(run_load(
            url, clients=args.clients, seconds=args.seconds, server_pid=pid,
            overload_clients=args.overload_clients if args.overload else 0, overload_seconds=args.overload_seconds,
            segment_seconds=args.segment_seconds, fmt=args.format, api_key=args.api_key))

    if args.url:
        url = args.url.rstrip("/")
        report = run(url, args.server_pid)
    else:
        env = {"T2M_MAX_QUEUE": str(args.max_queue)} if args.max_queue is not None else {}
        with running_server(args.model, env=env) as server:
            url = server.url
            report = run(url, server.pid)
    print(format_report(report, url))
    if args.json_out:
        Path(args.json_out).write_text(json.dumps(report.to_json(), indent=2))
    failed = report.server_errors > 0 or report.recovered is False
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
