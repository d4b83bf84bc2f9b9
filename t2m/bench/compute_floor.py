"""How far a masked-family model (MoMask, MoGenTS) is from this machine's arithmetic limit: the multiply-adds one
request costs, counted from the graphs themselves, against the rate this CPU reaches on a plain matrix product.

Every graph call a 10 s request makes is run once with onnxruntime's profiler at the request's shapes (the mask
stage's `steps` calls and the residual stage's `residual_layers - 1` calls of each branch, with guidance's cond and
null rows in one batch; one decoder call; one text call), and its MatMul / Gemm / Conv multiply-adds are summed from
the shapes the profiler records; each call is also timed without the profiler. The machine's rate is a lone
MatMul of the same width (rows x 384 x 1024, the transformers' feed-forward shape) in float32 and as a per-row int8
graph (the service's quantisation, t2m/export/writing/row_quantize.py), on 1 and 2 threads. The floor, the request's
multiply-adds at that rate, is what no schedule, graph rewrite or kernel choice on this machine can beat for the
released recipe (same steps, same guidance, same layers); the measured time beside it says how much is left.

    OMP_NUM_THREADS=1 t2m bench compute-floor --bundle WORKDIR/bundles/mogents
        [--bundle WORKDIR/bundles/mogents-int8] [--seconds 10] [--threads 1 2] [--repeats 3]
    (release bundles: t2m/bench/released_models.py --models mogents --schemes float32,int8 --workdir WORKDIR)
"""
from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
from onnx import TensorProto, helper

from t2m.bench.machine import machine_facts as machine
from t2m.export.writing.quantize import quantize_graph
from t2m.runtime.bundle_loader import session_options

__all__ = ["GraphCall", "count_macs", "main", "request_calls"]

MAC_OPS = {"MatMul", "FusedMatMul", "Gemm", "MatMulInteger", "DynamicQuantizeMatMul", "MatMulIntegerToFloat",
           "Conv", "FusedConv", "ConvInteger"}


@dataclass(frozen=True)
class GraphCall:
    """One graph a request calls `calls` times, with the batch it runs at (and its token length, if not the
    request's: the text graph's is the sentence's)."""

    graph: str
    calls: int
    batch: int
    tokens: int | None = None


def request_calls(manifest: dict) -> list[GraphCall]:
    """The graph calls of one one-sentence request of a masked-family bundle (t2m/families/masked/loop.py's loop)."""
    masked = manifest["masked"]
    guided = 2 if masked.get("unconditional_branch") and masked.get("guidance", 1.0) != 1.0 else 1
    residual = manifest["residual_layers"] - 1
    text_tokens = 77 if manifest.get("text_encoder", {}).get("kind") == "clip" else 16   # CLIP pads to 77
    calls = [GraphCall("text_encoder.onnx", 1, 1, text_tokens), GraphCall("masked.onnx", masked["steps"], guided),
             GraphCall("residual.onnx", residual, guided)]
    for branch in masked.get("branches", []):
        calls += [GraphCall(f"masked_{branch['name']}.onnx", masked["steps"], guided),
                  GraphCall(f"residual_{branch['name']}.onnx", residual, guided)]
    return calls + [GraphCall("decoder.onnx", 1, 1)]


def _feeds(session: ort.InferenceSession, batch: int, tokens: int) -> dict[str, np.ndarray]:
    """Inputs of the request's shapes: token ids and codes 0 (a valid code), layer 1, the full length."""
    feeds = {}
    for graph_input in session.get_inputs():
        shape = [batch if dim == "batch" else tokens if dim == "tokens" else dim for dim in graph_input.shape]
        if "int" in graph_input.type:
            ones = graph_input.name in ("layer", "attention_mask")
            fill = tokens if graph_input.name == "length" else 1 if ones else 0
            feeds[graph_input.name] = np.full(shape, fill, dtype=np.int64)
        else:
            feeds[graph_input.name] = np.random.default_rng(0).standard_normal(shape).astype(np.float32)
    return feeds


def count_macs(profile: list[dict]) -> float:
    """Multiply-adds of one profiled run: each matrix product's output size times its inner size (a convolution's:
    times its kernel's input channels and taps), from the shapes onnxruntime recorded."""
    total = 0.0
    for event in profile:
        args = event.get("args", {})
        if event.get("cat") != "Node" or args.get("op_name") not in MAC_OPS:
            continue
        inputs = [next(iter(shape.values())) for shape in args.get("input_type_shape", [])]
        outputs = [next(iter(shape.values())) for shape in args.get("output_type_shape", [])]
        if not inputs or not outputs:
            continue
        inner = np.prod(inputs[1][1:]) if "Conv" in args["op_name"] else inputs[0][-1]
        total += float(np.prod(outputs[0])) * float(inner)
    return total


def _session(path: Path, threads: int, profile: bool = False) -> ort.InferenceSession:
    """A session opened with the service's options (t2m.runtime.bundle_loader.session_options)."""
    options = session_options(threads, 1)
    options.enable_profiling = profile
    options.profile_file_prefix = str(Path(tempfile.gettempdir()) / "t2m_compute_floor")
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


def graph_macs(path: Path, batch: int, tokens: int) -> float:
    """Multiply-adds of one call of the graph at `path` (the last of two profiled runs, after its warm-up)."""
    session = _session(path, 1, profile=True)
    feeds = _feeds(session, batch, tokens)
    session.run(None, feeds)
    profile_file = Path(session.end_profiling())
    try:
        events = json.loads(profile_file.read_text())
    finally:
        profile_file.unlink(missing_ok=True)
    runs = [event for event in events if event.get("name") == "model_run"]
    last_start = runs[-1]["ts"] if runs else 0
    return count_macs([event for event in events if event.get("ts", 0) >= last_start])


def call_ms(path: Path, batch: int, tokens: int, threads: int, repeats: int) -> float:
    """Median wall ms of one call, after a warm-up call."""
    session = _session(path, threads)
    feeds = _feeds(session, batch, tokens)
    session.run(None, feeds)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        session.run(None, feeds)
        times.append((time.perf_counter() - start) * 1e3)
    return statistics.median(times)


def matmul_rate(rows: int, threads: int, repeats: int, int8: bool, folder: Path) -> float:
    """GMAC/s of a lone [rows, 384] x [384, 1024] MatMul (float32, or int8 with per-row activation scales)."""
    weight = np.random.default_rng(1).standard_normal((384, 1024)).astype(np.float32) * 0.05
    graph = helper.make_graph(
        [helper.make_node("MatMul", ["x", "w"], ["y"])], "matmul",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, ["rows", 384])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, ["rows", 1024])],
        [onnx.numpy_helper.from_array(weight, "w")])
    path = folder / "matmul.onnx"
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)]), path)
    if int8:
        path = quantize_graph(path, folder / "matmul_int8.onnx", per_row=True)
    session = _session(path, threads)
    x = np.random.default_rng(2).standard_normal((rows, 384)).astype(np.float32)
    session.run(None, {"x": x})
    inner = 20
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(inner):
            session.run(None, {"x": x})
        times.append((time.perf_counter() - start) / inner)
    return rows * 384 * 1024 / statistics.median(times) / 1e9


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--bundle", type=Path, action="append", required=True, help="a masked-family bundle")
    parser.add_argument("--seconds", type=float, default=10.0, help="the request's motion length (default 10)")
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    for bundle in args.bundle:
        manifest_path = bundle / "manifest.json"
        if not manifest_path.is_file():
            parser.error(f"--bundle {bundle}: no manifest.json there")
        manifest = json.loads(manifest_path.read_text())
        if manifest.get("family") != "masked":
            parser.error(f"--bundle {bundle}: family {manifest.get('family')!r}, this counts the masked family only")

    info = machine()
    print(f"- CPU: {info['cpu']}; load average {info['load_average']}; onnxruntime {info['onnxruntime']}")
    with tempfile.TemporaryDirectory() as scratch:
        rows = 600
        rates = {(threads, int8): matmul_rate(rows, threads, args.repeats, int8, Path(scratch))
                 for threads in args.threads for int8 in (False, True)}
    print(f"- this machine's rate on a lone {rows} x 384 x 1024 MatMul, GMAC/s: " + "; ".join(
        f"{threads} thread(s) float32 {rates[threads, False]:.1f}, int8 per row {rates[threads, True]:.1f}"
        for threads in args.threads))
    for bundle in args.bundle:
        manifest = json.loads((bundle / "manifest.json").read_text())
        tokens = min(manifest["max_tokens"], round(args.seconds * manifest["fps"] / manifest["frames_per_token"]))
        calls = [call for call in request_calls(manifest) if (bundle / call.graph).is_file()]
        int8 = any(str(label).startswith("int8") for label in (manifest.get("quantization") or {}).values())
        frames = tokens * manifest["frames_per_token"]
        print(f"\n## {manifest['name']} {manifest['version']} ({bundle.name}): a {frames}-frame request "
              f"({tokens} token rows), {'int8' if int8 else 'float32'} token graphs\n")
        header = " | ".join(f"ms per call, {threads} thread(s)" for threads in args.threads)
        print(f"| graph | calls | batch | GMAC per call | GMAC per request | {header} |")
        print("| --- | ---: | ---: | ---: | ---: | " + " | ".join("---:" for _ in args.threads) + " |")
        total_macs, total_ms = 0.0, dict.fromkeys(args.threads, 0.0)
        for call in calls:
            path = bundle / call.graph
            length = call.tokens or tokens
            macs = graph_macs(path, call.batch, length)
            ms = {threads: call_ms(path, call.batch, length, threads, args.repeats) for threads in args.threads}
            total_macs += macs * call.calls
            for threads in args.threads:
                total_ms[threads] += ms[threads] * call.calls
            print(f"| {call.graph} | {call.calls} | {call.batch} | {macs / 1e9:.2f} | {macs * call.calls / 1e9:.1f} | "
                  + " | ".join(f"{ms[threads]:.1f}" for threads in args.threads) + " |")
        print(f"\n- one request: {total_macs / 1e9:.0f} GMAC; its graph calls take "
              + ", ".join(f"{total_ms[threads] / 1e3:.2f} s on {threads} thread(s)" for threads in args.threads))
        for threads in args.threads:
            print(f"- floor on {threads} thread(s): {total_macs / rates[threads, False] / 1e9:.2f} s at the float32 "
                  f"rate, {total_macs / rates[threads, True] / 1e9:.2f} s at the int8 rate")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
