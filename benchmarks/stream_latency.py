"""Time to the first frame vs the whole motion over HTTP: a 10 s motion (one sentence) streamed ("stream": true)
against the same request answered whole, in one run, requests alternating so both see the same machine.

Per streamed request: the time until the client has parsed the first frames message, and until the end message
(the last frame has come before it). Per whole request: the time until its json body is read. Sequential requests
after a warm-up, so the figures are what a single user sees. Prints a markdown table.

    python -m benchmarks.stream_latency --model t2m/bundles/default --repeats 20     # starts its own server
    python -m benchmarks.stream_latency --model t2m/bundles/default --intra-op-threads 1     # on a shared machine
    python -m benchmarks.stream_latency --url http://127.0.0.1:8000 --repeats 20
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import httpx
import numpy as np

from benchmarks.http_latency import (
    MAX_REPEATS,
    add_target_arguments,
    check_target,
    motion_request,
    on_target,
    write_json,
)
from t2m.testing.server_process import require_loopback

__all__ = ["format_table", "main", "measure_stream"]

GOAL_FIRST_FRAME_MS = 30.0   # the goal for a 10 s motion on the default model


def _whole(client: httpx.Client, url: str, body: dict) -> float:
    started = time.perf_counter()
    response = client.post(f"{url}/generate", json=body)
    response.raise_for_status()
    response.json()
    return (time.perf_counter() - started) * 1000.0


def _streamed(client: httpx.Client, url: str, body: dict) -> tuple[float, float, int]:
    """(ms to the first frames, ms to the end message, frames messages)."""
    started = time.perf_counter()
    first = None
    chunks = 0
    with client.stream("POST", f"{url}/generate", json={**body, "stream": True}) as response:
        response.raise_for_status()
        for line in response.iter_lines():
            message = json.loads(line) if line else {}
            if message.get("type") == "frames":
                chunks += 1
                first = first if first is not None else time.perf_counter()
            elif message.get("type") == "end":
                break
            elif message.get("type") == "error":
                raise RuntimeError(f"stream failed: {message}")
    ended = time.perf_counter()
    if first is None:
        raise RuntimeError("the stream carried no frames")
    return (first - started) * 1000.0, (ended - started) * 1000.0, chunks


def _summary(values: list[float]) -> dict[str, float]:
    return {"p50_ms": float(np.percentile(values, 50)), "p95_ms": float(np.percentile(values, 95)),
            "mean_ms": float(np.mean(values))}


def measure_stream(url: str, *, repeats: int = 20, motion_seconds: float = 10.0, segments: int = 1,
                   api_key: str | None = None) -> dict:
    """p50/p95/mean of: the whole json answer, the stream's first frames and its last frame; frames messages."""
    require_loopback(url)
    if not 1 <= repeats <= MAX_REPEATS:
        raise ValueError(f"repeats: {repeats} is outside 1..{MAX_REPEATS}")
    headers = {"Authorization": f"Bearer {api_key}"} if api_key else {}
    whole, first, last, chunks = [], [], [], []
    with httpx.Client(timeout=300.0, headers=headers) as client:
        _whole(client, url, motion_request(motion_seconds, segments, "json", 0))        # warm-up
        _streamed(client, url, motion_request(motion_seconds, segments, "json", 0))
        for i in range(repeats):
            body = motion_request(motion_seconds, segments, "json", i + 1)
            whole.append(_whole(client, url, body))
            to_first, to_last, messages = _streamed(client, url, body)
            first.append(to_first)
            last.append(to_last)
            chunks.append(messages)
    return {"repeats": repeats, "motion_seconds": motion_seconds, "segments": segments,
            "whole": _summary(whole), "first_frame": _summary(first), "last_frame": _summary(last),
            "frames_messages": int(np.median(chunks))}


def format_table(result: dict, url: str) -> str:
    rows = [("whole json answer (stream false)", result["whole"]),
            ("stream: first frames", result["first_frame"]),
            ("stream: last frame (end message)", result["last_frame"])]
    lines = [f"### Time to the first frame vs the whole answer: a {result['motion_seconds']:g} s motion "
             f"({result['segments']} sentence(s)), {result['repeats']} requests each, alternating, {url}", "",
             "| what | p50 ms | p95 ms | mean ms |", "| --- | ---: | ---: | ---: |"]
    lines += [f"| {name} | {row['p50_ms']:.1f} | {row['p95_ms']:.1f} | {row['mean_ms']:.1f} |" for name, row in rows]
    verdict = "met" if result["first_frame"]["p50_ms"] <= GOAL_FIRST_FRAME_MS else "not met"
    lines += ["", f"frames messages per stream (median): {result['frames_messages']}; goal first frames <= "
                  f"{GOAL_FIRST_FRAME_MS:g} ms (p50): {verdict}"]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_target_arguments(parser, repeats=20)
    parser.add_argument("--intra-op-threads", type=int, default=None,
                        help="with --model: T2M_INTRA_OP_THREADS of the server it starts (default: the server's, 0 = "
                             "onnxruntime's choice; 1 is faster when other work shares the cores)")
    args = parser.parse_args(argv)
    try:
        check_target(args)
    except ValueError as error:
        print(f"stream_latency: error: {error}", file=sys.stderr)
        return 2
    env = {} if args.intra_op_threads is None else {"T2M_INTRA_OP_THREADS": str(args.intra_op_threads)}
    url, result = on_target(args, lambda url: measure_stream(url, repeats=args.repeats,
                                                             motion_seconds=args.motion_seconds,
                                                             segments=args.segments, api_key=args.api_key), env)
    print(format_table(result, url))
    write_json(args, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
