"""`step_order.py`'s phases without HTTP: the service's ContinuousBatcher driven by threads in the process, so the
figures are the scheduler's and the engine's alone (on a 2-core machine the HTTP benchmark's clients, uvicorn and
the answers' transfer share the cores with the engine). Before/after in one run: each phase runs in a child
process with this checkout's code or an older checkout's (`--before-code DIR`, e.g. `git worktree add DIR COMMIT`),
alternating, on the same bundle; each child loads the engine the way `t2m serve` does (T2M_INTRA_OP_THREADS and
T2M_BLAS_THREADS at 1) and warms it up first.

Phases: the 2 s probe alone (one request every --probe-interval-ms, open loop); mixed (the probe beside
--long-clients sending 30 s three-sentence requests back to back); long alone; sixteen (--clients asking for 10 s
back to back). Requests carry the model's default guidance, as the HTTP API's do. The table is step_order.py's.

    t2m bench scheduler --before-code /tmp/before --seconds 15 --rounds 3
"""
from __future__ import annotations

import argparse
import functools
import json
import os
import random
import subprocess
import sys
import threading
import time
from pathlib import Path

import t2m

REPO = Path(t2m.__file__).resolve().parents[1]   # the folder of this checkout's `t2m`


def run_phase_here(model: str, phase: str, seconds: float, long_clients: int, clients: int, interval_s: float,
                   seed: int, kinds: dict[str, tuple[float, int]], sentences: list[str]) -> dict[str, dict]:
    """The worker: one phase on a ContinuousBatcher of this process's `t2m` (whichever checkout PYTHONPATH
    names), its requests made as step_order.py makes them (`kinds`: kind -> (motion seconds, sentences), texts
    drawn from `sentences`; the parent passes step_order.KINDS and load_test.SENTENCES, which a worker running an
    older checkout cannot import); per kind its latencies (ms) and the phase's length."""
    from threadpoolctl import threadpool_limits

    from t2m.runtime.engine import OnnxEngine
    from t2m.runtime.scheduling import ContinuousBatcher
    from t2m.runtime.types import GenerationRequest, SegmentRequest

    engine = OnnxEngine.load(model, intra_op_threads=1)
    threadpool_limits(1)
    batcher = ContinuousBatcher(engine, max_queue=64)
    guidance = engine.limits.guidance()   # the model's default, as the HTTP API's requests get it

    def request(rng: random.Random, kind: str) -> GenerationRequest:
        motion, count = kinds[kind]
        return GenerationRequest([SegmentRequest(rng.choice(sentences), motion / count) for _ in range(count)],
                                 seed=rng.randrange(2**31), guidance=guidance)

    for kind in kinds:
        batcher.submit_nowait(request(random.Random(0), kind)).result()
    users = {"short alone": {"short": 1}, "long alone": {"long": long_clients},
             "mixed": {"short": 1, "long": long_clients}, "sixteen": {"ten": clients}}[phase]
    latencies: dict[str, list[float]] = {kind: [] for kind in users}
    lock = threading.Lock()
    deadline = time.monotonic() + seconds

    def record(kind: str, started: float) -> None:
        with lock:
            latencies[kind].append((time.perf_counter() - started) * 1e3)

    def back_to_back(kind: str, rng: random.Random) -> None:
        while time.monotonic() < deadline:
            started = time.perf_counter()
            batcher.submit_nowait(request(rng, kind)).result()
            record(kind, started)

    def probe(rng: random.Random) -> None:
        sent = []
        while time.monotonic() < deadline:
            started = time.perf_counter()
            future = batcher.submit_nowait(request(rng, "short"))
            future.add_done_callback(functools.partial(lambda started, _: record("short", started), started))
            sent.append(future)
            time.sleep(interval_s)
        for future in sent:
            future.result()

    started = time.monotonic()
    threads = []
    for k, (kind, n) in enumerate(users.items()):
        for i in range(n):
            rng = random.Random(seed * 10_000 + k * 1000 + i)
            target, args = (probe, (rng,)) if kind == "short" else (back_to_back, (kind, rng))
            threads.append(threading.Thread(target=target, args=args))
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    elapsed = time.monotonic() - started
    batcher.close()
    return {kind: {"latencies_ms": values, "seconds": elapsed} for kind, values in latencies.items()}


def run_phase_in_child(code: Path, args: argparse.Namespace, phase: str, seed: int) -> dict[str, dict]:
    """One phase in a child process running `code`'s t2m, with step_order.py's requests."""
    from t2m.bench.phases import KINDS, SENTENCES

    env = {**os.environ, "PYTHONPATH": str(code), "OMP_NUM_THREADS": "1"}
    command = [sys.executable, str(Path(__file__).resolve()), "--worker", phase,
               "--model", str(Path(args.model).resolve()), "--seconds", str(args.seconds),
               "--long-clients", str(args.long_clients), "--clients", str(args.clients),
               "--probe-interval-ms", str(args.probe_interval_ms), "--seed", str(seed),
               "--workload", json.dumps({"kinds": KINDS, "sentences": SENTENCES})]
    done = subprocess.run(command, cwd=code, env=env, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"the {phase} phase with the code in {code} failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--model", default="t2m/bundles/default")
    parser.add_argument("--seconds", type=float, default=15.0)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--phases", default="short alone,long alone,mixed,sixteen")
    parser.add_argument("--long-clients", type=int, default=3)
    parser.add_argument("--clients", type=int, default=16)
    parser.add_argument("--probe-interval-ms", type=float, default=200.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--before-code", type=Path, help="a checkout of an older commit (its t2m is the 'before')")
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    parser.add_argument("--workload", help=argparse.SUPPRESS)   # the worker's kinds and sentences, as JSON
    args = parser.parse_args(argv)
    if args.worker:
        workload = json.loads(args.workload)
        kinds = {kind: (float(motion), int(count)) for kind, (motion, count) in workload["kinds"].items()}
        print(json.dumps(run_phase_here(args.model, args.worker, args.seconds, args.long_clients, args.clients,
                                        args.probe_interval_ms / 1e3, args.seed, kinds, workload["sentences"])))
        return 0
    if args.before_code is not None and not (args.before_code / "t2m" / "__init__.py").is_file():
        parser.error(f"--before-code {args.before_code}: not a checkout of this repository")
    if not 1 <= args.rounds <= 20 or not 0 < args.seconds <= 600:
        parser.error("--rounds must be 1 to 20 and --seconds 0 to 600")

    from t2m.bench.machine import machine_facts as machine
    from t2m.bench.phases import PhaseResult, format_table

    sides = {"after": REPO} if args.before_code is None else {"before": args.before_code.resolve(), "after": REPO}
    phases = [phase for phase in args.phases.split(",") if phase]
    raw: dict[tuple[str, str, str], list[PhaseResult]] = {}
    for round_index in range(args.rounds):
        for phase in phases:
            order = list(sides) if round_index % 2 == 0 else list(reversed(sides))
            for side in order:
                figures = run_phase_in_child(sides[side], args, phase, seed=args.seed + round_index)
                for kind, values in figures.items():
                    result = PhaseResult(name=kind, clients=0, seconds=values["seconds"],
                                         latencies_ms=values["latencies_ms"], status_2xx=len(values["latencies_ms"]))
                    raw.setdefault((side, phase, kind), []).append(result)
                print(f"round {round_index + 1} {phase} {side}: "
                      + ", ".join(f"{kind} {len(v['latencies_ms'])} answers" for kind, v in figures.items()),
                      flush=True)
    pooled = {key: PhaseResult.pooled(results[0].name, 0, results) for key, results in raw.items()}
    info = machine()
    print(f"\n## Short requests first, engine level (no HTTP): {args.model}, {args.rounds} round(s) of "
          f"{args.seconds:g} s phases\n")
    print(f"- CPU: {info['cpu']}; load average at the end {info['load_average']}; onnxruntime "
          f"{info['onnxruntime']}; one onnxruntime and one BLAS thread per engine, as `t2m serve` by default")
    print("- " + "; ".join(f"{side}: the code in {'this checkout' if path == REPO else path}"
                           for side, path in sides.items()))
    print(f"- command: t2m bench scheduler {' '.join(argv if argv is not None else sys.argv[1:])}\n")
    print(format_table(pooled, dict.fromkeys(sides, "its default order")))
    return 0


if __name__ == "__main__":
    if "--worker" not in sys.argv:   # the parent imports `benchmarks.*`; a worker's `t2m` is its PYTHONPATH's
            raise SystemExit(main())
