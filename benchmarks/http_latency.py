"""End-to-end HTTP latency of one motion (default 10 s) by output format: json vs bvh vs glb.

Sequential requests (one at a time, after a warm-up) so the figure is the latency a single user sees, including
text encoding, sampling, decoding, the format conversion and the HTTP round trip. Prints a markdown table.

    python -m benchmarks.http_latency --url http://127.0.0.1:8000 --repeats 10
    python -m benchmarks.http_latency --model t2m/bundles/default --repeats 10      # starts its own server
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import httpx
import numpy as np

from t2m.testing.server_process import require_loopback, running_server

__all__ = ["add_target_arguments", "check_target", "format_table", "main", "measure_latency", "on_target",
           "write_json"]

T = TypeVar("T")

FORMATS = ("json", "bvh", "glb")
MAX_REPEATS = 200
TEXTS = ["a person walks forward", "a person turns around", "a person waves with the right hand",
         "a person jumps", "a person sits down"]


def motion_request(motion_seconds: float, segments: int, fmt: str, seed: int) -> dict:
    """`segments` sentences sharing `motion_seconds` equally."""
    each = motion_seconds / segments
    return {"segments": [{"text": TEXTS[i % len(TEXTS)], "duration": each} for i in range(segments)],
            "format": fmt, "seed": seed}


def measure_latency(url: str, *, repeats: int = 10, motion_seconds: float = 10.0, segments: int = 1,
                    formats: tuple[str, ...] = FORMATS, api_key: str | None = None) -> list[dict]:
    """Per format: p50/p95/mean latency in ms and the response size, over `repeats` sequential requests."""
    require_loopback(url)
    if not 1 <= repeats <= MAX_REPEATS:
        raise ValueError(f"repeats: {repeats} is outside 1..{MAX_REPEATS}")
    headers = {"Authorization": f"Bearer {api_key}"} if api_key else {}
    rows = []
    with httpx.Client(timeout=300.0, headers=headers) as client:
        warm = client.post(f"{url}/generate", json=motion_request(motion_seconds, segments, "json", 0))
        warm.raise_for_status()
        for fmt in formats:
            latencies, sizes = [], []
            for i in range(repeats):
                started = time.perf_counter()
                response = client.post(f"{url}/generate", json=motion_request(motion_seconds, segments, fmt, i + 1))
                elapsed = (time.perf_counter() - started) * 1000.0
                if response.status_code != 200:
                    raise RuntimeError(f"{fmt}: HTTP {response.status_code}: {response.text[:300]}")
                latencies.append(elapsed)
                sizes.append(len(response.content))
            rows.append({"format": fmt, "repeats": repeats, "p50_ms": float(np.percentile(latencies, 50)),
                         "p95_ms": float(np.percentile(latencies, 95)), "mean_ms": float(np.mean(latencies)),
                         "bytes": int(np.median(sizes))})
    return rows


def format_table(rows: list[dict], url: str, motion_seconds: float, segments: int) -> str:
    lines = [f"### HTTP latency of a {motion_seconds:g} s motion ({segments} segment(s)), sequential, {url}", "",
             "| format | requests | p50 ms | p95 ms | mean ms | response KiB |",
             "| --- | ---: | ---: | ---: | ---: | ---: |"]
    for row in rows:
        lines.append(f"| {row['format']} | {row['repeats']} | {row['p50_ms']:.0f} | {row['p95_ms']:.0f} | "
                     f"{row['mean_ms']:.0f} | {row['bytes'] / 1024:.1f} |")
    return "\n".join(lines)


def add_target_arguments(parser: argparse.ArgumentParser, repeats: int) -> None:
    """What the latency benchmarks share: --url or --model, --repeats, the motion, --api-key, --json-out."""
    target = parser.add_mutually_exclusive_group(required=True)
    target.add_argument("--url", help="a running service on loopback, e.g. http://127.0.0.1:8000")
    target.add_argument("--model", help="start `t2m serve` on this bundle on a free loopback port and time that")
    parser.add_argument("--repeats", type=int, default=repeats)
    parser.add_argument("--motion-seconds", type=float, default=10.0)
    parser.add_argument("--segments", type=int, default=1, help="split the motion into this many sentences")
    parser.add_argument("--api-key")
    parser.add_argument("--json-out", help="also write the figures as JSON here")


def check_target(args: argparse.Namespace) -> None:
    """ValueError for a --url off this machine or --repeats out of bounds, before anything is sent."""
    if args.url:
        require_loopback(args.url)
    if not 1 <= args.repeats <= MAX_REPEATS:
        raise ValueError(f"--repeats: {args.repeats} is outside 1..{MAX_REPEATS}")


def on_target(args: argparse.Namespace, measure: Callable[[str], T], env: dict[str, str] | None = None,
              ) -> tuple[str, T]:
    """(url, measure(url)) on --url, or on a `t2m serve` started on --model (with `env`) for the measurement."""
    if args.url:
        url = args.url.rstrip("/")
        return url, measure(url)
    with running_server(args.model, env=env) as server:
        return server.url, measure(server.url)


def write_json(args: argparse.Namespace, figures: Any) -> None:
    if args.json_out:
        Path(args.json_out).write_text(json.dumps(figures, indent=2))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_target_arguments(parser, repeats=10)
    parser.add_argument("--formats", default=",".join(FORMATS), help="comma-separated subset of json,bvh,glb")
    args = parser.parse_args(argv)
    formats = tuple(f.strip() for f in args.formats.split(",") if f.strip())
    try:
        check_target(args)
        unknown = set(formats) - set(FORMATS)
        if unknown:
            raise ValueError(f"--formats: unknown {sorted(unknown)}; choose from {','.join(FORMATS)}")
    except ValueError as error:
        print(f"http_latency: error: {error}", file=sys.stderr)
        return 2
    url, rows = on_target(args, lambda url: measure_latency(url, repeats=args.repeats,
                                                            motion_seconds=args.motion_seconds,
                                                            segments=args.segments, formats=formats,
                                                            api_key=args.api_key))
    print(format_table(rows, url, args.motion_seconds, args.segments))
    write_json(args, rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
