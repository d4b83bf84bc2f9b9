"""Before/after continuous batching in one run: two `t2m serve` processes on the same bundle, one with
T2M_CONTINUOUS_BATCHING=false (a batch runs to its end), one with true (requests join and leave at step boundaries),
driven by the same clients in alternating phases so that both see the same machine.

Two workloads, each run against both servers in every round (order before, after, then after, before, ...):
  mixed    --long-clients send 10 s three-sentence requests back to back while --short-clients send 2 s one-sentence
           requests back to back: p50/p99 latency of the short ones (and of the long ones), throughput.
  sixteen  --clients (16) send 10 s one-sentence motions back to back: throughput and p50/p99.
Both servers get a warm-up request first; latencies of all rounds are pooled per server and workload. The machine
(CPU, cores, load average before and after) is printed with the tables, so a run on a shared machine says so.
Loopback only; bounded like load_test.py.

    python -m benchmarks.continuous_batching --model t2m/bundles/gpt --seconds 30 --rounds 2
"""
from __future__ import annotations

import argparse
import asyncio
import functools
import json
import random
import sys
import time
from collections.abc import Callable
from pathlib import Path

import httpx

from benchmarks.load_test import MAX_CLIENTS, MAX_SECONDS, SENTENCES, PhaseResult, post_and_record
from t2m.bench.machine import machine_facts as machine
from t2m.testing.server_process import require_loopback, running_server

__all__ = ["MODES", "WORKLOADS", "machine", "main", "run_workload", "warm_up"]

MODES = {"before": "false", "after": "true"}          # label -> T2M_CONTINUOUS_BATCHING
WORKLOADS = ("mixed", "sixteen")
MAX_ROUNDS = 20


def _body(rng: random.Random, seconds: float, sentences: int) -> dict:
    """`sentences` sentences sharing `seconds`, a fresh seed, the model's default guidance."""
    return {"segments": [{"text": rng.choice(SENTENCES), "duration": seconds / sentences} for _ in range(sentences)],
            "seed": rng.randrange(2**31)}


async def _client(client: httpx.AsyncClient, url: str, make_body: Callable[[], dict], result: PhaseResult,
                  deadline: float) -> None:
    """One user: a request, then the next as soon as it is answered, until the deadline."""
    while time.monotonic() < deadline:
        response = await post_and_record(client, url, make_body(), result)
        if response is not None and response.status_code == 429:
            await asyncio.sleep(float(response.headers.get("Retry-After", "1") or 1))


async def run_workload(url: str, workload: str, seconds: float, *, clients: int, long_clients: int,
                       short_clients: int, seed: int) -> dict[str, PhaseResult]:
    """One phase of `workload` against `url`: per request kind its PhaseResult (requests in flight at the deadline
    are awaited and counted)."""
    require_loopback(url)
    kinds: dict[str, tuple[int, float, int]] = (   # kind -> (clients, motion seconds, sentences)
        {"short 2 s": (short_clients, 2.0, 1), "long 10 s x3": (long_clients, 10.0, 3)} if workload == "mixed"
        else {"10 s": (clients, 10.0, 1)})
    results = {kind: PhaseResult(name=kind, clients=n, seconds=seconds) for kind, (n, _, _) in kinds.items()}
    total = sum(n for n, _, _ in kinds.values())
    limits = httpx.Limits(max_connections=total, max_keepalive_connections=total)
    async with httpx.AsyncClient(timeout=600.0, limits=limits) as client:
        started = time.monotonic()
        deadline = started + seconds
        tasks = []
        for k, (kind, (n, motion, sentences)) in enumerate(kinds.items()):
            for i in range(n):
                tasks.append(_client(client, url, functools.partial(
                    _body, random.Random(seed * 10_000 + k * 1000 + i), motion, sentences), results[kind], deadline))
        await asyncio.gather(*tasks)
        for result in results.values():
            result.seconds = time.monotonic() - started
    return results


def warm_up(url: str) -> None:
    """One request of each kind before timing: a fresh server's first graph calls are slower."""
    require_loopback(url)
    rng = random.Random(0)
    with httpx.Client(timeout=600.0) as client:
        for seconds, sentences in ((2.0, 1), (10.0, 3)):
            client.post(f"{url}/generate", json=_body(rng, seconds, sentences)).raise_for_status()


def _pool(phases: list[PhaseResult]) -> PhaseResult:
    return PhaseResult.pooled(phases[0].name, phases[0].clients, phases)


def _ms(value: float | None) -> str:
    return "-" if value is None else f"{value:.0f}"


def format_tables(pooled: dict[tuple[str, str, str], PhaseResult]) -> str:
    """One table per workload: per server and request kind, requests, answers/s, p50/p95/p99, errors."""
    lines = []
    for workload in WORKLOADS:
        rows = {key: result for key, result in pooled.items() if key[0] == workload}
        if not rows:
            continue
        lines += [f"### {workload}", "", "| server | request kind | clients | answers/s | p50 ms | p95 ms | p99 ms | "
                  "non-2xx |", "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
        for (_, mode, kind), result in sorted(rows.items(), key=lambda item: (item[0][2], item[0][1] != "before")):
            s = result.summary()
            errors = s["4xx"] + s["429"] + s["5xx"] + s["connection_errors"]
            lines.append(f"| {mode} (continuous {MODES[mode]}) | {kind} | {s['clients']} | {s['ok_per_s']:.2f} | "
                         f"{_ms(s['p50_ms'])} | {_ms(s['p95_ms'])} | {_ms(s['p99_ms'])} | {errors} |")
        lines.append("")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--model", default="t2m/bundles/gpt", help="bundle served by both servers")
    parser.add_argument("--seconds", type=float, default=30.0, help="length of each phase")
    parser.add_argument("--rounds", type=int, default=2, help="each workload against each server this many times")
    parser.add_argument("--workloads", default=",".join(WORKLOADS))
    parser.add_argument("--clients", type=int, default=16, help="sixteen: concurrent clients")
    parser.add_argument("--long-clients", type=int, default=4, help="mixed: clients sending 10 s 3-sentence requests")
    parser.add_argument("--short-clients", type=int, default=2, help="mixed: clients sending 2 s requests")
    parser.add_argument("--intra-op-threads", type=int, default=1, help="the servers' T2M_INTRA_OP_THREADS")
    parser.add_argument("--startup-timeout", type=float, default=900.0, help="seconds a server may take to load")
    parser.add_argument("--json-out", help="also write the figures as JSON here")
    args = parser.parse_args(argv)
    workloads = [w.strip() for w in args.workloads.split(",") if w.strip()]
    problems = [f"--workloads: unknown {w!r}" for w in workloads if w not in WORKLOADS]
    problems += [f"{name}: {value} is outside 1..{MAX_CLIENTS}" for name, value in
                 (("--clients", args.clients), ("--long-clients", args.long_clients),
                  ("--short-clients", args.short_clients)) if not 1 <= value <= MAX_CLIENTS]
    problems += [] if 0 < args.seconds <= MAX_SECONDS else [f"--seconds: outside (0, {MAX_SECONDS:g}]"]
    problems += [] if 1 <= args.rounds <= MAX_ROUNDS else [f"--rounds: outside 1..{MAX_ROUNDS}"]
    if problems:
        print(f"continuous_batching: error: {'; '.join(problems)}", file=sys.stderr)
        return 2

    env = {"T2M_MAX_QUEUE": "256", "T2M_REQUEST_TIMEOUT_S": "600", "T2M_INTRA_OP_THREADS": str(args.intra_op_threads),
           "T2M_VERIFY_HASHES": "false"}   # loading is not what is measured
    before = machine()
    phases: dict[tuple[str, str, str], list[PhaseResult]] = {}
    start = {"startup_timeout_s": args.startup_timeout}
    with running_server(args.model, env={**env, "T2M_CONTINUOUS_BATCHING": MODES["before"]}, **start) as old, \
            running_server(args.model, env={**env, "T2M_CONTINUOUS_BATCHING": MODES["after"]}, **start) as new:
        servers = {"before": old.url, "after": new.url}
        for url in servers.values():
            warm_up(url)
        for round_index in range(args.rounds):
            order = list(MODES) if round_index % 2 == 0 else list(reversed(MODES))
            for workload in workloads:
                for mode in order:
                    results = asyncio.run(run_workload(
                        servers[mode], workload, args.seconds, clients=args.clients, long_clients=args.long_clients,
                        short_clients=args.short_clients, seed=round_index))
                    for kind, result in results.items():
                        phases.setdefault((workload, mode, kind), []).append(result)
                    print(f"round {round_index + 1} {workload} {mode}: " + ", ".join(
                        f"{kind} {r.status_2xx} answers" for kind, r in results.items()), file=sys.stderr)
    after = machine()
    pooled = {key: _pool(results) for key, results in phases.items()}
    print(f"## Continuous batching, before/after ({args.model}, {args.rounds} round(s) of {args.seconds:g} s phases)")
    print()
    print(f"- CPU: {before['cpu']}; Python {before['python']}, onnxruntime {before['onnxruntime']}, "
          f"numpy {before['numpy']}; servers T2M_INTRA_OP_THREADS={args.intra_op_threads}")
    print(f"- load average (1, 5, 15 min): {before['load_average']} before, {after['load_average']} after")
    print(f"- command: python -m benchmarks.continuous_batching {' '.join(argv if argv is not None else sys.argv[1:])}")
    print()
    print(format_tables(pooled))
    if args.json_out:
        Path(args.json_out).write_text(json.dumps({"machine": {"before": before, "after": after}, "args": vars(args),
                                                   "results": [{"workload": w, "server": m, "kind": k, **r.summary()}
                                                               for (w, m, k), r in pooled.items()]}, indent=2))
    return 1 if any(r.status_5xx or r.connection_errors for r in pooled.values()) else 0


if __name__ == "__main__":
    sys.exit(main())
