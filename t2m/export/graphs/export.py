"""One way to turn a torch module into an ONNX file, shared by the decoder, GPT-step and text graphs.

Exporter choice (torch 2.13): the legacy TorchScript exporter (``dynamo=False``), opset 17.
Both exporters produce graphs that onnxruntime runs with dynamic batch/length axes and a
zero-length KV cache, and both match PyTorch to ~3e-7 on the GPT step. The dynamo exporter gives
a smaller graph with symbolic output dims ("past + 1"), but takes 5-11 s per graph here versus
0.2-0.5 s for the legacy one (measured on a toy 2-layer step graph on this 2-core machine), which
would make ``build_random_bundle`` and the parity tests miss their time budgets; onnxruntime's own
graph optimiser removes the legacy exporter's extra Shape/Gather nodes at session creation. The
legacy exporter's DeprecationWarning is silenced here, in one place, so switching is a one-line change
(``USE_DYNAMO``; tests/export/test_parity.py checks that path too, as a slow test).
"""
from __future__ import annotations

import io
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import torch

if TYPE_CHECKING:
    import onnx

OPSET = 17
USE_DYNAMO = False


def export_graph(
    module: torch.nn.Module,
    args: tuple[torch.Tensor, ...],
    path: str | Path,
    input_names: Sequence[str],
    output_names: Sequence[str],
    dynamic_axes: Mapping[str, Mapping[int, str]],
) -> Path:
    """Export ``module(*args)`` to ``path`` with named inputs/outputs and dynamic axes; check it with onnx."""
    import onnx

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    module = module.eval()
    with torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # legacy-exporter deprecation and tracer warnings about shape-constant code
        if USE_DYNAMO:
            from torch.export import Dim

            dims: dict[str, Dim] = {}
            shapes = {
                name: {axis: dims.setdefault(label, Dim(label)) for axis, label in dynamic_axes.get(name, {}).items()}
                or None
                for name in input_names
            }
            program = torch.onnx.export(
                module, args, input_names=list(input_names), output_names=list(output_names),
                dynamic_shapes=shapes, dynamo=True, opset_version=max(OPSET, 18),
            )
            assert program is not None  # dynamo=True always returns the program
            model = program.model_proto
        else:
            buffer = io.BytesIO()  # in memory: the graph is pinned, checked and written once (1 GB for T2M-GPT)
            # torch annotates f as a path, but the TorchScript exporter writes to file-like objects too
            torch.onnx.export(
                module, args, buffer,  # type: ignore[arg-type]
                input_names=list(input_names), output_names=list(output_names),
                dynamic_axes={k: dict(v) for k, v in dynamic_axes.items()}, opset_version=OPSET, dynamo=False,
                do_constant_folding=True,
            )
            model = onnx.load_from_string(buffer.getvalue())
            del buffer
        _pin_static_dims(model, module, args, input_names, output_names, dynamic_axes)
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def _pin_static_dims(
    model: onnx.ModelProto,
    module: torch.nn.Module,
    args: tuple[torch.Tensor, ...],
    input_names: Sequence[str],
    output_names: Sequence[str],
    dynamic_axes: Mapping[str, Mapping[int, str]],
) -> None:
    """Declare every axis not listed as dynamic with its concrete size (in place).

    The legacy exporter leaves some fixed output dims symbolic (e.g. "Divtext_features_dim_1"); a
    graph that states its fixed sizes lets the bundle check compare them with the manifest.
    """
    outputs = module(*args)
    outputs = outputs if isinstance(outputs, (tuple, list)) else (outputs,)
    shapes = {**dict(zip(input_names, (a.shape for a in args))), **dict(zip(output_names, (o.shape for o in outputs)))}
    for value in [*model.graph.input, *model.graph.output]:
        if value.name not in shapes:
            continue
        dynamic = dynamic_axes.get(value.name, {})
        for axis, dim in enumerate(value.type.tensor_type.shape.dim):
            if axis not in dynamic and not dim.HasField("dim_value"):
                dim.dim_value = int(shapes[value.name][axis])


def ort_session(path: str | Path, threads: int = 1, optimization: str = "all"):
    """An onnxruntime CPU session with a fixed thread count (tests and benchmarks must not oversubscribe 2 cores)."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.log_severity_level = 3
    levels = {
        "all": ort.GraphOptimizationLevel.ORT_ENABLE_ALL,
        "basic": ort.GraphOptimizationLevel.ORT_ENABLE_BASIC,
        "none": ort.GraphOptimizationLevel.ORT_DISABLE_ALL,
    }
    options.graph_optimization_level = levels[optimization]
    return ort.InferenceSession(str(path), sess_options=options, providers=["CPUExecutionProvider"])
