"""Short requests first, before/after in one run: two `t2m serve` processes on the same bundle, both with continuous
batching, one stepping every cohort at every step boundary (T2M_STEP_ORDER=every-cohort, the order before
shortest-first), one running the shortest work first (shortest-first, the default), driven by the same clients in
alternating phases so that both see the same machine.

Phases, each against both servers in every round (order before, after, then after, before, ...):
  short alone  a probe sends a 2 s one-sentence request every --probe-interval-ms (200), whether or not the last one
               was answered (open loop: the short work offered is the same in both servers, so what the long requests
               lose is the order's doing, not a faster probe asking for more)
  long alone   --long-clients send 30 s three-sentence requests (3 x 10 s) back to back
  mixed        both at once: the probe's latency under the long load, and the long load's answers/s beside the probe
  sixteen      --clients (16) send 10 s one-sentence requests back to back
The table: the probe's p50/p90 alone and under load and their ratio (the goal: p90 under load at most 2x alone), the
long requests' answers/s alone and beside the probe (what they lose to it), and the 16-client answers/s and p99.
Loopback only; bounded like load_test.py.

    python -m benchmarks.step_order --model t2m/bundles/default --seconds 20 --rounds 2
    # "before" = the code of an older commit (its own default order), e.g. the commit before shortest-first scheduling:
    git worktree add /tmp/before 5164bad && python -m benchmarks.step_order --before-code /tmp/before
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

from benchmarks.load_test import MAX_CLIENTS, MAX_SECONDS, post_and_record
from t2m.bench.machine import machine_facts as machine
from t2m.bench.phases import KINDS, MODES, SENTENCES, PhaseResult, format_table
from t2m.testing.server_process import require_loopback, running_server

__all__ = ["PHASES", "main", "run_phase"]

PHASES = ("short alone", "long alone", "mixed", "sixteen")
MAX_ROUNDS = 20


def _body(rng: random.Random, kind: str) -> dict:
    seconds, sentences = KINDS[kind]
    return {"segments": [{"text": rng.choice(SENTENCES), "duration": seconds / sentences} for _ in range(sentences)],
            "seed": rng.randrange(2**31)}


async def _client(client: httpx.AsyncClient, url: str, make_body: Callable[[], dict], result: PhaseResult,
                  deadline: float, pause_s: float = 0.0) -> None:
    """One user: a request, then the next as soon as it is answered, until the deadline."""
    while time.monotonic() < deadline:
        response = await post_and_record(client, url, make_body(), result)
        if response is not None and response.status_code == 429:
            await asyncio.sleep(float(response.headers.get("Retry-After", "1") or 1))


async def _probe(client: httpx.AsyncClient, url: str, make_body: Callable[[], dict], result: PhaseResult,
                 deadline: float, interval_s: float) -> None:
    """Open loop: a request every `interval_s` until the deadline, each timed on its own; all awaited at the end."""
    sent = []
    while time.monotonic() < deadline:
        sent.append(asyncio.create_task(post_and_record(client, url, make_body(), result)))
        await asyncio.sleep(interval_s)
    await asyncio.gather(*sent)


async def run_phase(url: str, phase: str, seconds: float, *, long_clients: int, clients: int, probe_interval_s: float,
                    seed: int) -> dict[str, PhaseResult]:
    """One phase against `url`: per request kind its PhaseResult (requests in flight at the deadline are awaited)."""
    require_loopback(url)
    users: dict[str, tuple[int, float]] = {   # kind -> (clients, 0 = back to back, else the probe's interval)
        "short alone": {"short": (1, probe_interval_s)}, "long alone": {"long": (long_clients, 0.0)},
        "mixed": {"short": (1, probe_interval_s), "long": (long_clients, 0.0)}, "sixteen": {"ten": (clients, 0.0)},
    }[phase]
    results = {kind: PhaseResult(name=kind, clients=n, seconds=seconds) for kind, (n, _) in users.items()}
    total = sum(n for n, _ in users.values())
    limits = httpx.Limits(max_connections=total, max_keepalive_connections=total)
    async with httpx.AsyncClient(timeout=600.0, limits=limits) as client:
        started = time.monotonic()
        deadline = started + seconds
        tasks = []
        for k, (kind, (n, pause)) in enumerate(users.items()):
            for i in range(n):
                make_body = functools.partial(_body, random.Random(seed * 10_000 + k * 1000 + i), kind)
                user = _probe if pause else _client
                tasks.append(user(client, url, make_body, results[kind], deadline, pause))
        await asyncio.gather(*tasks)
        for result in results.values():
            result.seconds = time.monotonic() - started
    return results


def _warm_up(url: str) -> None:
    rng = random.Random(0)
    with httpx.Client(timeout=600.0) as client:
        for kind in KINDS:
            client.post(f"{url}/generate", json=_body(rng, kind)).raise_for_status()


def phase_figures(pooled: dict[tuple[str, str, str], PhaseResult]) -> list[dict]:
    """--json-out's results: per (server, phase, kind) the phase's summary and its p90. The key's phase ("short
    alone", "mixed", ...) replaces the summary's own name, which is only the request kind."""
    return [{**result.summary(), "server": server, "phase": phase, "kind": kind, "p90_ms": result.percentile(90)}
            for (server, phase, kind), result in pooled.items()]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--model", default="t2m/bundles/default", help="bundle served by both servers")
    parser.add_argument("--seconds", type=float, default=20.0, help="length of each phase")
    parser.add_argument("--rounds", type=int, default=2, help="each phase against each server this many times")
    parser.add_argument("--phases", default=",".join(PHASES))
    parser.add_argument("--long-clients", type=int, default=3, help="clients sending 30 s three-sentence requests")
    parser.add_argument("--clients", type=int, default=16, help="sixteen: concurrent clients")
    parser.add_argument("--probe-interval-ms", type=float, default=200.0, help="the probe sends one request this often")
    parser.add_argument("--intra-op-threads", type=int, default=1, help="the servers' T2M_INTRA_OP_THREADS")
    parser.add_argument("--max-step-skips", type=int, default=None,
                        help="the 'after' server's T2M_MAX_STEP_SKIPS (default: the setting's default)")
    parser.add_argument("--before-code", help="a checkout of an older commit: the 'before' server runs its code "
                                              "instead of this one")
    parser.add_argument("--before-model", help="the bundle the 'before' server serves (default: --model), e.g. the "
                                               "older commit's own copy of it")
    parser.add_argument("--before-step-order", default=MODES["before"], choices=sorted(set(MODES.values())),
                        help="the 'before' server's T2M_STEP_ORDER")
    parser.add_argument("--before-env", action="append", default=[], metavar="T2M_NAME=VALUE",
                        help="a setting for the 'before' server only (repeatable), e.g. T2M_BLAS_THREADS=0")
    parser.add_argument("--startup-timeout", type=float, default=900.0, help="seconds a server may take to load")
    parser.add_argument("--json-out", help="also write the figures as JSON here")
    args = parser.parse_args(argv)
    phases = [p.strip() for p in args.phases.split(",") if p.strip()]
    problems = [f"--phases: unknown {p!r}" for p in phases if p not in PHASES]
    problems += [f"{name}: {value} is outside 1..{MAX_CLIENTS}" for name, value in
                 (("--clients", args.clients), ("--long-clients", args.long_clients)) if not 1 <= value <= MAX_CLIENTS]
    problems += [] if 0 < args.seconds <= MAX_SECONDS else [f"--seconds: outside (0, {MAX_SECONDS:g}]"]
    problems += [] if 1 <= args.rounds <= MAX_ROUNDS else [f"--rounds: outside 1..{MAX_ROUNDS}"]
    problems += [] if 20 <= args.probe_interval_ms <= 10_000 else ["--probe-interval-ms: outside 20..10000"]
    before_env = dict(item.split("=", 1) for item in args.before_env if "=" in item)
    problems += [f"--before-env: {item!r} is not T2M_NAME=VALUE" for item in args.before_env
                 if "=" not in item or not item.startswith("T2M_")]
    if problems:
        print(f"step_order: error: {'; '.join(problems)}", file=sys.stderr)
        return 2

    env = {"T2M_MAX_QUEUE": "256", "T2M_REQUEST_TIMEOUT_S": "600", "T2M_INTRA_OP_THREADS": str(args.intra_op_threads),
           "T2M_VERIFY_HASHES": "false", "T2M_CONTINUOUS_BATCHING": "true"}
    before = machine()
    results: dict[tuple[str, str, str], list[PhaseResult]] = {}
    start = {"startup_timeout_s": args.startup_timeout}
    model = str(Path(args.model).resolve())
    orders = {**MODES, "before": args.before_step_order}
    with running_server(str(Path(args.before_model or args.model).resolve()),
                        env={**env, "T2M_STEP_ORDER": orders["before"], **before_env}, code_dir=args.before_code,
                        **start) as old, \
            running_server(model, env={**env, "T2M_STEP_ORDER": MODES["after"], **(
                {} if args.max_step_skips is None else {"T2M_MAX_STEP_SKIPS": str(args.max_step_skips)})},
                **start) as new:
        servers = {"before": old.url, "after": new.url}
        for url in servers.values():
            _warm_up(url)
        for round_index in range(args.rounds):
            order = list(MODES) if round_index % 2 == 0 else list(reversed(MODES))
            for phase in phases:
                for mode in order:
                    got = asyncio.run(run_phase(servers[mode], phase, args.seconds, long_clients=args.long_clients,
                                                clients=args.clients, probe_interval_s=args.probe_interval_ms / 1000,
                                                seed=round_index))
                    for kind, result in got.items():
                        results.setdefault((mode, phase, kind), []).append(result)
                    print(f"round {round_index + 1} {phase} {mode}: " + ", ".join(
                        f"{kind} {r.status_2xx} answers" for kind, r in got.items()), file=sys.stderr)
    after = machine()
    pooled = {key: PhaseResult.pooled(key[2], phases_[0].clients, phases_) for key, phases_ in results.items()}
    print(f"## Short requests first, before/after ({args.model}, {args.rounds} round(s) of {args.seconds:g} s phases)")
    print()
    print(f"- CPU: {before['cpu']}; Python {before['python']}, onnxruntime {before['onnxruntime']}, "
          f"numpy {before['numpy']}; servers T2M_INTRA_OP_THREADS={args.intra_op_threads}, continuous batching")
    print(f"- load average (1, 5, 15 min): {before['load_average']} before, {after['load_average']} after")
    if args.before_code or args.before_model or before_env:
        print(f"- before: the code in {args.before_code or 'this checkout'} serving {args.before_model or args.model}"
              f" ({orders['before']}{''.join(f', {k}={v}' for k, v in before_env.items())}); after: this checkout "
              f"serving {args.model}")
    print(f"- command: python -m benchmarks.step_order {' '.join(argv if argv is not None else sys.argv[1:])}")
    print(f"- short: 2 s, one sentence, one every {args.probe_interval_ms:g} ms (open loop); long: "
          f"30 s as 3 x 10 s sentences, {args.long_clients} clients back to back; 16 clients: 10 s, one sentence")
    print()
    print(format_table(pooled, orders))
    if args.json_out:
        Path(args.json_out).write_text(json.dumps({"machine": {"before": before, "after": after}, "args": vars(args),
                                                   "results": phase_figures(pooled)}, indent=2))
    return 1 if any(r.status_5xx or r.connection_errors for r in pooled.values()) else 0


if __name__ == "__main__":
    sys.exit(main())
