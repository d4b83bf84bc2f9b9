"""The compose scale-out topology run for real on loopback: replicas behind nginx with deploy/nginx.conf.

Two measurements, printed as markdown:
  throughput  requests/s through nginx with 1, 2, 3 ... replicas (the same clients and requests for each count).
  failover    a load test through nginx during which one replica is killed (SIGKILL) and restarted, and then
              another is stopped (SIGTERM) and restarted: requests sent, failed (must be 0), requests nginx retried on
              another replica (its access log), the killed replica's recovery time, its requests after rejoining.

Replicas are containers of an image (--image, host network) or `t2m serve` processes (no --image). Everything runs
niced and on 127.0.0.1. Re-run it on an idle machine for throughput figures that are not depressed by other work:

    python -m benchmarks.scale_out --image t2m-service:smoke --replicas 1,2,3 --seconds 30 --failover
"""
from __future__ import annotations

import argparse
import asyncio
import json
import os
import signal
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

from benchmarks.load_test import PhaseResult, run_phase
from t2m.testing.nginx_front import NginxFront, read_access_log, running_nginx
from t2m.testing.replicas import Replica, make_replicas
from t2m.testing.server_process import free_port

__all__ = ["FailoverReport", "failover", "main", "throughput"]


def _failed(result: PhaseResult) -> int:
    return result.requests - result.status_2xx


async def _after(delay_s: float, action: Callable[[], float]) -> float:
    await asyncio.sleep(delay_s)
    return await asyncio.to_thread(action)


def throughput(front: NginxFront, replicas: list[Replica], counts: list[int], clients: int,
               seconds: float) -> list[dict]:
    """For each count, nginx is reloaded with the first `count` replicas and loaded for `seconds`."""
    rows = []
    for count in counts:
        front.set_replicas([r.port for r in replicas[:count]])
        time.sleep(1.0)  # the reload's new workers take over
        result = asyncio.run(run_phase(front.url, f"{count} replicas", clients, seconds))
        load = os.getloadavg()[0]
        summary = result.summary()
        rows.append({"replicas": count, "clients": clients, "seconds": summary["seconds"],
                     "requests": result.requests, "ok": result.status_2xx, "failed": _failed(result),
                     "ok_per_s": summary["ok_per_s"], "ok_per_s_per_replica": round(summary["ok_per_s"] / count, 3),
                     "p50_ms": summary["p50_ms"], "p95_ms": summary["p95_ms"], "load_1min": round(load, 2)})
    return rows


@dataclass
class FailoverReport:
    requests: int
    ok: int
    failed: int
    retried: int
    retried_from_killed: int
    retried_from_stopped: int
    seconds: float
    kill_recovery_s: float
    killed_ok_after_rejoin: int
    stopped_exit_code: int
    stop_drain_s: float
    error_samples: list[str]


def failover(front: NginxFront, replicas: list[Replica], clients: int, seconds: float) -> FailoverReport:
    """Load through nginx; after `seconds` / 4 replica 0 is killed (SIGKILL) and restarted at once, after `seconds` / 2
    replica 1 is stopped (SIGTERM: it drains) and restarted; the load goes on until both are back and serving."""
    killed, stopped = replicas[0], replicas[1]
    log_start = len(read_access_log(front.access_log))
    timings: dict[str, float] = {}

    def kill_and_restart() -> float:
        started = time.monotonic()
        killed.signal(signal.SIGKILL)
        killed.wait_exit(30)
        killed.start()
        killed.wait_healthy()
        timings["rejoined_at_line"] = len(read_access_log(front.access_log))
        return time.monotonic() - started

    def stop_and_restart() -> float:
        started = time.monotonic()
        stopped.signal(signal.SIGTERM)
        timings["exit_code"] = stopped.wait_exit(120)
        drained = time.monotonic() - started
        stopped.start()
        stopped.wait_healthy()
        return drained

    async def run() -> tuple[list[PhaseResult], float, float]:
        """Load in chunks until both replicas are back, then `seconds` / 2 more in which the rejoined serve too."""
        kill = asyncio.create_task(_after(seconds / 4, kill_and_restart))
        stop = asyncio.create_task(_after(seconds / 2, stop_and_restart))
        chunks: list[PhaseResult] = []
        while not (kill.done() and stop.done()) or not chunks:
            chunks.append(await run_phase(front.url, "failover", clients, min(5.0, seconds)))
        chunks.append(await run_phase(front.url, "after rejoining", clients, seconds / 2))
        return chunks, await kill, await stop

    chunks, recovery_s, drain_s = asyncio.run(run())
    result = PhaseResult.pooled("failover", clients, chunks)
    lines = read_access_log(front.access_log)[log_start:]
    generate = [line for line in lines if "/generate" in line.request]
    retried = [line for line in generate if line.retried]
    killed_addr, stopped_addr = f"127.0.0.1:{killed.port}", f"127.0.0.1:{stopped.port}"
    rejoined = read_access_log(front.access_log)[int(timings["rejoined_at_line"]):]
    return FailoverReport(
        requests=result.requests, ok=result.status_2xx, failed=_failed(result), retried=len(retried),
        retried_from_killed=sum(line.upstreams[0] == killed_addr for line in retried),
        retried_from_stopped=sum(line.upstreams[0] == stopped_addr for line in retried),
        seconds=round(result.seconds, 1), kill_recovery_s=round(recovery_s, 2),
        killed_ok_after_rejoin=sum(line.upstreams[-1] == killed_addr and line.status == 200 for line in rejoined),
        stopped_exit_code=int(timings["exit_code"]), stop_drain_s=round(drain_s, 2),
        error_samples=result.error_samples[:5])


def format_throughput(rows: list[dict]) -> str:
    lines = ["| replicas | clients | s | requests | failed | ok/s | ok/s per replica | p50 ms | p95 ms | load avg |",
             "| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for row in rows:
        lines.append(f"| {row['replicas']} | {row['clients']} | {row['seconds']:.0f} | {row['requests']} | "
                     f"{row['failed']} | {row['ok_per_s']:.2f} | {row['ok_per_s_per_replica']:.2f} | "
                     f"{row['p50_ms'] or 0:.0f} | {row['p95_ms'] or 0:.0f} | {row['load_1min']:.1f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--image", help="run the replicas as containers of this image (default: t2m serve processes)")
    parser.add_argument("--replicas", default="1,2,3", help="replica counts to measure, e.g. 1,2,3")
    parser.add_argument("--clients", type=int, default=6)
    parser.add_argument("--seconds", type=float, default=30.0, help="per replica count, and for the failover run")
    parser.add_argument("--failover", action="store_true", help="also kill and stop replicas under load")
    parser.add_argument("--workdir", type=Path, help="nginx's files and the replicas' logs (default: a temp dir)")
    parser.add_argument("--json-out", type=Path)
    args = parser.parse_args(argv)
    counts = sorted({int(c) for c in args.replicas.split(",") if c.strip()})
    if not counts or counts[0] < 1 or counts[-1] > 8:
        print("scale_out: error: --replicas must be counts in 1..8", file=sys.stderr)
        return 2
    workdir = args.workdir or Path(tempfile.mkdtemp(prefix="t2m-scale-out-"))
    needed = max(counts[-1], 2 if args.failover else 1)
    replicas = make_replicas(needed, workdir, image=args.image)
    out: dict = {"image": args.image, "load_1min_before": os.getloadavg()[0], "cpus": os.cpu_count()}
    try:
        for replica in replicas:
            replica.start()
        for replica in replicas:
            replica.wait_healthy()
        with running_nginx([r.port for r in replicas[:counts[0]]], free_port(), workdir / "nginx") as front:
            out["throughput"] = throughput(front, replicas, counts, args.clients, args.seconds)
            print(f"### Throughput through nginx ({'containers of ' + args.image if args.image else 'processes'}, "
                  f"{os.cpu_count()} CPUs)\n")
            print(format_throughput(out["throughput"]))
            if args.failover:
                front.set_replicas([r.port for r in replicas])
                time.sleep(1.0)
                report = failover(front, replicas, args.clients, args.seconds)
                out["failover"] = asdict(report)
                print(f"\n### Failover ({len(replicas)} replicas, {args.clients} clients, {args.seconds:g} s)\n")
                print("\n".join(f"- {key}: {value}" for key, value in asdict(report).items()))
                print(f"\nnginx access log: {front.access_log}")
    finally:
        for replica in replicas:
            replica.remove()
    if args.json_out:
        args.json_out.write_text(json.dumps(out, indent=2))
    failed = out.get("failover", {}).get("failed", 0) + sum(row["failed"] for row in out.get("throughput", []))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
