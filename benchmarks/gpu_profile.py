"""Where a GPU step's time goes: onnxruntime's own profile of a batch-1 run of the suite's cases, summed
per operator and provider, beside the wall time of the same run.

Why: the GPU suite (benchmarks/gpu_suite.py) found every loop far slower at batch 1 than its arithmetic needs (the
default model 6.3 ms per step of 7 graph calls; T2M-GPT's 228M step 3.6 ms where reading its weights takes 0.3 ms).
This says how much of a run is kernels on the device, how much is copies between host and device, and which
operators run on the CPU provider, which decides what to change first (CUDA graphs, device-side sampling, fewer
shape operators).
    python -m benchmarks.gpu_profile --out OUT [--device cuda|cpu] [--models default,t2m-gpt-release]
        [--graphs float32] [--tiny]
Prints one table per case; OUT/profile_<case>.json keeps onnxruntime's raw profile of the timed run.
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import onnxruntime as ort

from benchmarks import gpu_suite

REPO = Path(__file__).resolve().parents[1]

PROFILED: list[ort.InferenceSession] = []
SUITE_SESSION = gpu_suite.session


def profiled_session(path: Path, execution: Any,
                     options: ort.SessionOptions | None = None) -> ort.InferenceSession:
    """gpu_suite.session with onnxruntime's profiler on (its file written when the session ends its profiling)."""
    from t2m.runtime.bundle_loader import session_options

    options = options or session_options(0, 1)
    options.enable_profiling = True
    options.profile_file_prefix = str(Path(tempfile.gettempdir()) / f"ortprof_{path.stem}")
    session = SUITE_SESSION(path, execution, options)
    PROFILED.append(session)
    return session


def summarise(events: list[dict[str, Any]]) -> dict[str, Any]:
    """Node time per (operator, provider) and the session runs' total, in ms."""
    nodes: dict[tuple[str, str], list[float]] = defaultdict(lambda: [0.0, 0])
    runs = 0.0
    for event in events:
        if event.get("cat") == "Node" and event.get("name", "").endswith("_kernel_time"):
            args = event.get("args", {})
            key = (args.get("op_name", "?"), args.get("provider", "?"))
            nodes[key][0] += event.get("dur", 0) / 1000
            nodes[key][1] += 1
        elif event.get("cat") == "Session" and event.get("name") == "model_run":
            runs += event.get("dur", 0) / 1000
    return {"runs_ms": runs, "nodes": {f"{op} ({provider})": {"ms": ms, "calls": int(calls)}
                                       for (op, provider), (ms, calls) in nodes.items()}}


def profile_case(case: Any, device: str, out: Path) -> None:
    from t2m.runtime.execution import Execution

    PROFILED.clear()
    providers = ("cuda",) if device == "cuda" else ("cpu",)
    generate = case.onnx(Execution(providers, io_binding="on"))
    generate(1)                                           # warm-up (profiled too; the summary is of the whole)
    started = time.perf_counter()
    generate(1)
    wall = 1000 * (time.perf_counter() - started)
    events: list[dict[str, Any]] = []
    for session in PROFILED:
        events += json.loads(Path(session.end_profiling()).read_text())
    summary = summarise(events)
    (out / f"profile_{case.label.split()[0]}.json").write_text(json.dumps(summary, indent=1))
    nodes = sorted(summary["nodes"].items(), key=lambda item: -item[1]["ms"])
    kernel_ms = sum(entry["ms"] for _, entry in nodes)
    print(f"\n### {case.label}, batch 1, two runs profiled (warm-up + timed); timed run wall {wall:.1f} ms\n")
    print(f"session runs {summary['runs_ms']:.1f} ms, node kernels {kernel_ms:.1f} ms "
          f"({100 * kernel_ms / max(summary['runs_ms'], 1e-9):.0f}% of the runs)\n")
    print("| operator (provider) | ms | calls | us per call |\n| --- | ---: | ---: | ---: |")
    for name, entry in nodes[:15]:
        print(f"| {name} | {entry['ms']:.2f} | {entry['calls']} | {1000 * entry['ms'] / max(entry['calls'], 1):.1f} |")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").strip().splitlines()[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--device", choices=("cuda", "cpu"), default="cuda")
    parser.add_argument("--models", default="default,t2m-gpt-release")
    parser.add_argument("--graphs", choices=gpu_suite.GRAPHS, default="float32")
    parser.add_argument("--tiny", action="store_true")
    args = parser.parse_args(argv)
    if args.device == "cuda":
        gpu_suite.load_cuda_libraries()
    args.out.mkdir(parents=True, exist_ok=True)
    gpu_suite.session = profiled_session                  # every graph the cases open is profiled
    with tempfile.TemporaryDirectory(prefix="gpu-profile-") as temporary:
        workdir = Path(temporary)
        gpu_suite.GRAPH_VARIANT = gpu_suite.Graphs(args.graphs, workdir)
        builders = {"default": gpu_suite.embedded_hifigpt_case,
                    "t2m-gpt-release": lambda: gpu_suite.release_gpt_case(workdir, args.tiny),
                    "momask-release": lambda: gpu_suite.release_momask_case(workdir, args.tiny)}
        for name in args.models.split(","):
            profile_case(builders[name.strip()](), args.device, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
