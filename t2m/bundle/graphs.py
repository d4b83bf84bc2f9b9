"""The graphs' signatures: which inputs and outputs each ONNX file of a bundle must declare, for its manifest.

Both readers of graphs use `check_graph_io`: the exporter feeds it what `onnx` reads from the file, the service what
onnxruntime's session declares, so a bundle passes or fails the same check in both places.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from t2m.bundle.errors import BundleError
from t2m.bundle.family import get_family
from t2m.bundle.manifest import family_of

__all__ = [
    "ENCODER_GRAPH",
    "FLOAT32",
    "INT64",
    "DeclaredTensor",
    "GraphSpec",
    "TensorSpec",
    "branch_graphs",
    "bundle_graphs",
    "check_graph_io",
    "encoder_graph",
    "expected_graphs",
    "features_output",
    "kv_shape",
    "text_graph",
]

INT64 = "int64"
FLOAT32 = "float32"
# the optional graph that turns a motion's normalised features into the codes its decoder reads (uploaded motions)
ENCODER_GRAPH = "encoder.onnx"
# optional in a gpt-family bundle: the step over a fixed-capacity cache that T2M_CUDA_GRAPHS replays
FIXED_STEP_GRAPH = "gpt_step_fixed.onnx"


@dataclass(frozen=True)
class TensorSpec:
    """Name, element type and shape of one graph input/output; an int dim is checked, None is free (dynamic)."""

    name: str
    dtype: str
    shape: tuple[int | None, ...]


@dataclass(frozen=True)
class GraphSpec:
    inputs: tuple[TensorSpec, ...]
    outputs: tuple[TensorSpec, ...]


@dataclass(frozen=True)
class DeclaredTensor:
    """What a graph file declares for one input/output: dims are ints where fixed, else a name or None."""

    name: str
    dtype: str
    shape: tuple[int | str | None, ...]


def text_graph(manifest: Mapping[str, Any]) -> GraphSpec:
    dim = manifest["text_encoder"]["dim"]
    return GraphSpec(
        inputs=(TensorSpec("input_ids", INT64, (None, None)), TensorSpec("attention_mask", INT64, (None, None))),
        outputs=(TensorSpec("text_features", FLOAT32, (None, dim)),))


def branch_graphs(name: str) -> tuple[str, str]:
    """(token graph, residual graph) file names of a further token generator named `name` (the bundle contract's
    `masked_<name>.onnx`, `residual_<name>.onnx`: MoGenTS's 1D branch)."""
    return f"masked_{name}.onnx", f"residual_{name}.onnx"


def kv_shape(layers: int, block: Mapping[str, Any]) -> tuple[int | None, ...]:
    """A KV cache [layers, 2, B, n_head, P, head_dim] (B and P dynamic) of a block with n_head and head_dim."""
    return (layers, 2, None, block["n_head"], None, block["head_dim"])


def features_output(manifest: Mapping[str, Any]) -> tuple[TensorSpec, ...]:
    """decoder.onnx's output: de-normalised features [B, frames, D]."""
    return (TensorSpec("features", FLOAT32, (None, None, manifest["feature_dim"])),)


def expected_graphs(manifest: Mapping[str, Any]) -> dict[str, GraphSpec]:
    """The input/output names, types and (static where known) dims each graph must have for this manifest: the
    text graph, then the family's graphs and decoder."""
    return {"text_encoder.onnx": text_graph(manifest), **get_family(family_of(manifest)).graphs(manifest)}


def encoder_graph(manifest: Mapping[str, Any]) -> GraphSpec | None:
    """encoder.onnx's signature: normalised features [B, frames, D] -> `codes` of exactly the decoder's input layout
    (so whatever it encodes the decoder reads back); None for a family whose decoder reads no codes."""
    family = get_family(family_of(manifest))
    if not family.encodes:
        return None
    decoder = family.graphs(manifest)["decoder.onnx"]
    return GraphSpec(inputs=(TensorSpec("features", FLOAT32, (None, None, manifest["feature_dim"])),),
                     outputs=(TensorSpec("codes", INT64, decoder.inputs[0].shape),))


def bundle_graphs(manifest: Mapping[str, Any]) -> dict[str, GraphSpec]:
    """Every graph a bundle of this manifest holds, with its signature: the expected ones, the family's captured
    graphs and encoder.onnx where the manifest's `files` lists them (optional: a bundle without an encoder is valid
    and cannot encode uploaded motions; one without a captured graph has no CUDA-graph step)."""
    listed = manifest.get("files", {})
    graphs = expected_graphs(manifest)
    captured = get_family(family_of(manifest)).captured_graphs(manifest)   # e.g. gpt_step_fixed.onnx
    graphs.update({file: spec for file, spec in captured.items() if file in listed})
    if ENCODER_GRAPH not in listed:
        return graphs
    encoder = encoder_graph(manifest)
    if encoder is None:
        raise BundleError(f"{ENCODER_GRAPH}: family {family_of(manifest)!r} reads no codes and has no encoder graph")
    return {**graphs, ENCODER_GRAPH: encoder}


def _check_tensors(file: str, role: str, declared: Sequence[DeclaredTensor], expected: tuple[TensorSpec, ...]) -> None:
    found = {tensor.name: tensor for tensor in declared}
    for spec in expected:
        if spec.name not in found:
            raise BundleError(f"{file}: graph has no {role} {spec.name!r} (has {sorted(found)})")
        tensor = found[spec.name]
        if tensor.dtype != spec.dtype:
            raise BundleError(f"{file}: {role} {spec.name!r} has type {tensor.dtype}, expected {spec.dtype}")
        if len(tensor.shape) != len(spec.shape):
            raise BundleError(f"{file}: {role} {spec.name!r} has rank {len(tensor.shape)}, expected "
                              f"{len(spec.shape)}")
        for axis, (got, want) in enumerate(zip(tensor.shape, spec.shape)):
            if want is not None and isinstance(got, int) and got != want:
                raise BundleError(f"{file}: {role} {spec.name!r} has size {got} on axis {axis}, the manifest "
                                  f"implies {want}")
    unexpected = set(found) - {spec.name for spec in expected}
    if unexpected:
        raise BundleError(f"{file}: unexpected graph {role}s {sorted(unexpected)} (the manifest implies "
                          f"{[spec.name for spec in expected]})")


def check_graph_io(file: str, inputs: Sequence[DeclaredTensor], outputs: Sequence[DeclaredTensor],
                   spec: GraphSpec) -> None:
    """Names, element types, ranks and static dims of a graph's declared inputs and outputs against `spec`."""
    _check_tensors(file, "input", inputs, spec.inputs)
    _check_tensors(file, "output", outputs, spec.outputs)
