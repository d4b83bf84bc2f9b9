"""Several processes serving one embedded model on one device at once (benchmarks/gpu_suite.py --processes N): how
many 10 s motions per second they give together.

Why: on a GPU the default model's large batches are bound by the host (docs/gpu.md: at batch 1,024 the H100's
host loop took 1,399 of the 1,911 ms), and that loop is Python, so threads cannot run two of them at once. Processes
can: each has its own sessions on the same GPU and its own host loop on its own core, and while one samples on the
host another's calls run on the device. The service runs that way with `t2m serve --workers N` (one engine per
process). Each process builds the case itself, warms up, then all start together (a barrier) and generate and
decode `repeats` batches; the row's time is the slowest process's, so motions/s counts every process's motions over
the same wall time.
"""
from __future__ import annotations

import gc
import multiprocessing
import threading
import time
from pathlib import Path
from typing import Any

EMBEDDED = ("gpt", "default", "masked")   # cases a process can build without writing files (release cases write)


def _serve_batches(name: str, graphs: str, workdir: str, device: str, batch: int, repeats: int, barrier: Any,
                   results: Any) -> None:
    """One process: the case's onnxruntime sampler and decoder, a warm-up, the barrier, `repeats` timed batches."""
    import torch

    from benchmarks import gpu_suite as suite
    from t2m.runtime.execution import Execution

    try:
        torch.set_grad_enabled(False)
        if device == "cuda":
            suite.load_cuda_libraries()
        suite.GRAPH_VARIANT = suite.Graphs(graphs, Path(workdir))
        case = suite.case_builders(Path(workdir), tiny=True)[name]()
        providers = ("cuda",) if device == "cuda" else ("cpu",)
        generate = case.onnx(Execution(providers, io_binding="on") if case.kv_cache else Execution(providers))
        decoder = suite.session(case.decoder, Execution(providers))

        def one() -> None:
            decoder.run(None, {"codes": generate(batch)})

        one()
        gc.collect()
        gc.freeze()   # as the service does once its models are loaded
    except BaseException as error:     # the others must not wait at the barrier for this one
        barrier.abort()
        results.put(f"{type(error).__name__}: {str(error).splitlines()[0][:300]}")
        return
    try:
        barrier.wait()
    except threading.BrokenBarrierError:
        results.put("another process failed before the start")
        return
    started = time.perf_counter()
    for _ in range(repeats):
        one()
    results.put(time.perf_counter() - started)


def processes_wall_s(name: str, graphs: str, workdir: Path, device: str, processes: int, batch: int,
                     repeats: int, timeout_s: float = 300.0) -> float:
    """Seconds from the common start until the last of `processes` processes has generated and decoded `repeats`
    batches of `batch` motions of case `name` (one of EMBEDDED); raises RuntimeError naming a process's failure."""
    if name not in EMBEDDED:
        raise ValueError(f"--processes runs the embedded cases ({', '.join(EMBEDDED)}), not {name!r}")
    context = multiprocessing.get_context("spawn")   # CUDA does not survive fork
    barrier, results = context.Barrier(processes), context.Queue()
    workers = [context.Process(target=_serve_batches, args=(name, graphs, str(workdir), device, batch, repeats,
                                                            barrier, results)) for _ in range(processes)]
    for worker in workers:
        worker.start()
    try:
        outcomes = [results.get(timeout=timeout_s) for _ in workers]
    finally:
        for worker in workers:
            worker.join(timeout=10)
            if worker.is_alive():
                worker.terminate()
    failures = [outcome for outcome in outcomes if isinstance(outcome, str)]
    if failures:
        raise RuntimeError(failures[0])
    return max(outcomes)
