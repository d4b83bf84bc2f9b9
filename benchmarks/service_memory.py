"""Memory of a running service: each bundle served alone, then all of them in one `t2m serve`.

Starts `t2m serve` on loopback for each configuration, sends a few 10 s requests to every model it holds (so the
onnxruntime arenas have grown to their working size), then reads the server process's resident memory (VmRSS) and its
peak (VmHWM) from /proc. Prints a markdown table. Linux only.

    python -m benchmarks.service_memory --model t2m/bundles/default --model t2m/bundles/masked
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import httpx

from t2m.testing.server_process import running_server

__all__ = ["main", "measure", "process_memory_mb"]

REQUEST = {"segments": [{"text": "a person walks forward", "duration": 4.0},
                        {"text": "a person waves with the right hand", "duration": 3.0},
                        {"text": "a person bows", "duration": 3.0}], "format": "json"}


def process_memory_mb(pid: int) -> tuple[float, float]:
    """(VmRSS, VmHWM) of a process in MB."""
    fields = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key, _, value = line.partition(":")
        if key in ("VmRSS", "VmHWM"):
            fields[key] = int(value.split()[0]) / 1024.0  # kB -> MB
    return fields["VmRSS"], fields["VmHWM"]


def measure(models: list[Path], requests_per_model: int = 5) -> dict:
    """Serve `models` in one process (the first is the default), warm every model up, return its memory."""
    with running_server(models[0], extra_models=models[1:]) as server:
        idle_rss, _ = process_memory_mb(server.pid)
        with httpx.Client(timeout=300.0) as client:
            names = [m["name"] for m in client.get(f"{server.url}/health").json()["models"]]
            for name in names:
                for seed in range(requests_per_model):
                    response = client.post(f"{server.url}/generate", json={**REQUEST, "model": name, "seed": seed})
                    response.raise_for_status()
        rss, peak = process_memory_mb(server.pid)
    return {"models": names, "idle_rss_mb": idle_rss, "rss_mb": rss, "peak_mb": peak}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").strip().splitlines()[0])
    parser.add_argument("--model", type=Path, action="append", required=True, help="a bundle (repeat)")
    parser.add_argument("--requests", type=int, default=5, help="10 s requests per model before measuring")
    parser.add_argument("--json-out", type=Path, default=None)
    args = parser.parse_args(argv)
    configurations = [[model] for model in args.model] + ([args.model] if len(args.model) > 1 else [])
    rows = [measure(models, args.requests) for models in configurations]
    print("| models served | RSS at start (MB) | RSS after requests (MB) | peak RSS (MB) |")
    print("| --- | ---: | ---: | ---: |")
    for row in rows:
        print(f"| {' + '.join(row['models'])} | {row['idle_rss_mb']:.0f} | {row['rss_mb']:.0f} |"
              f" {row['peak_mb']:.0f} |")
    print(f"\n{args.requests} three-sentence 10 s requests per model (json) before reading /proc/PID/status.")
    if args.json_out:
        args.json_out.write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
