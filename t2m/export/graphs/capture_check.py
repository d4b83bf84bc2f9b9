"""Will onnxruntime's CUDA provider capture this graph as a CUDA graph? Answered here, on a machine without a GPU.

Why: `enable_cuda_graph` refuses a session whose partition holds a Memcpy node ("all compute graph nodes have not
been partitioned to the CUDAExecutionProvider"), and that is found out only on a GPU, where device time is scarce
(docs/gpu.md: MoMask's release graphs failed so on an H100, 2026-11-27). The copies come from shape arithmetic:
the CUDA provider keeps the outputs of Shape and Size in host memory, and places on the CPU each node whose inputs
are all such host tensors, small initializers or graph inputs (onnxruntime's fallback_cpu_capability.cc,
GetCpuPreferredNodes). Where a host tensor then meets a device kernel at an input that kernel reads from the
device, onnxruntime inserts a copy: `torch.arange(tokens.shape[1]) < length[:, None]` is exactly that (Range on
the CPU, Less on the device).

`capture_blockers` replays that placement rule on the graph after onnxruntime's basic (provider-independent)
optimisations, with the CUDA kernels' host-memory inputs listed below, and names every edge that would need a copy.
It is a model of onnxruntime's rule, not onnxruntime itself: its verdict was checked against the H100 (the
fixed-cache GPT step captured; MoMask's masked and residual graphs with Range did not) and a GPU run remains the
judge.
"""
from __future__ import annotations

import tempfile
from pathlib import Path

import onnx

__all__ = ["CUDA_HOST_INPUTS", "capture_blockers"]

# Inputs that onnxruntime's CUDA kernels read from host memory (OrtMemTypeCPUInput in their kernel definitions),
# for the operators that consume shape arithmetic in this project's graphs. An operator not listed reads every
# input from the device.
CUDA_HOST_INPUTS: dict[str, frozenset[int]] = {
    "Reshape": frozenset({1}), "Expand": frozenset({1}), "ConstantOfShape": frozenset({0}),
    "Slice": frozenset({1, 2, 3, 4}), "Unsqueeze": frozenset({1}), "Squeeze": frozenset({1}),
    "Tile": frozenset({1}), "TopK": frozenset({1}), "Split": frozenset({1}), "Pad": frozenset({1, 2, 3}),
    "OneHot": frozenset({1}), "CumSum": frozenset({1}), "Trilu": frozenset({1}), "Resize": frozenset({1, 2, 3}),
    "ReduceSum": frozenset({1}), "ReduceMean": frozenset({1}), "ReduceMax": frozenset({1}),
    "ReduceMin": frozenset({1}), "ReduceProd": frozenset({1}),
}
HOST_OUTPUT_OPS = frozenset({"Shape", "Size"})   # the CUDA provider's kernels for these write host memory
SMALL_INITIALIZER = 100                             # elements; fallback_cpu_capability.cc's kSmallInitializerThreshold


def _basic_optimised(path: Path) -> onnx.ModelProto:
    """The graph as onnxruntime partitions it: after constant folding and the other basic rewrites."""
    import onnxruntime as ort

    with tempfile.TemporaryDirectory(prefix="capture-check-") as folder:
        optimised = Path(folder) / "basic.onnx"
        options = ort.SessionOptions()
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_BASIC
        options.optimized_model_filepath = str(optimised)
        ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        return onnx.load(str(optimised))


def capture_blockers(path: str | Path) -> list[str]:
    """One line per tensor the CUDA provider would copy between host and device inside a run of the graph at
    `path` (an empty list: capturable, as far as this model of the placement rule goes)."""
    graph = _basic_optimised(Path(path)).graph
    small = {init.name for init in graph.initializer if _elements(init) <= SMALL_INITIALIZER}
    graph_inputs = {value.name for value in graph.input}
    consumers: dict[str, list[onnx.NodeProto]] = {}
    for node in graph.node:
        for name in node.input:
            consumers.setdefault(name, []).append(node)
    host: set[str] = set()          # tensors in host memory
    on_cpu: set[int] = set()        # nodes the provider would place on the CPU (by id)
    for node in graph.node:         # onnx keeps nodes in topological order
        if node.op_type in HOST_OUTPUT_OPS:
            host.update(node.output)
            continue
        reads_host = any(name in host for name in node.input)
        if reads_host and all(_cpu_readable(node, slot, name, host, small, graph_inputs)
                              for slot, name in enumerate(node.input) if name):
            on_cpu.add(id(node))
            host.update(node.output)
    blockers = []
    for node in graph.node:
        if node.op_type in HOST_OUTPUT_OPS or id(node) in on_cpu:
            continue
        for slot, name in enumerate(node.input):
            if name in host and slot not in CUDA_HOST_INPUTS.get(node.op_type, frozenset()):
                producer = next((n for n in graph.node if name in n.output), None)
                blockers.append(f"{node.op_type} {node.name!r} reads host tensor {name!r} (from "
                                f"{producer.op_type if producer else '?'} on the CPU) at input {slot}")
    return blockers


def _cpu_readable(node: onnx.NodeProto, slot: int, name: str, host: set[str], small: set[str],
                  graph_inputs: set[str]) -> bool:
    """GetCpuPreferredNodes's test for one input: a small initializer or a graph input, or a host tensor that the
    CUDA kernel would not have read from the host anyway."""
    if name in small or name in graph_inputs:
        return True
    return name in host and slot not in CUDA_HOST_INPUTS.get(node.op_type, frozenset())


def _elements(initializer: onnx.TensorProto) -> int:
    count = 1
    for dim in initializer.dims:
        count *= dim
    return count
