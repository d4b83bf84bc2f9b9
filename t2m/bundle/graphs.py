"""The graphs' signatures: which inputs and outputs each ONNX file of a bundle must declare, for its manifest.

Both readers of graphs use `check_graph_io`: the exporter feeds it what `onnx` reads from the file, the service what
onnxruntime's session declares, so a bundle passes or fails the same check in both places.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from t2m.bundle.errors import BundleError
from t2m.bundle.manifest import branch_graphs

__all__ = ["DeclaredTensor", "GraphSpec", "TensorSpec", "check_graph_io", "expected_graphs"]

INT64 = "int64"
FLOAT32 = "float32"


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


def _text_graph(manifest: Mapping[str, Any]) -> GraphSpec:
    dim = manifest["text_encoder"]["dim"]
    return GraphSpec(
        inputs=(TensorSpec("input_ids", INT64, (None, None)), TensorSpec("attention_mask", INT64, (None, None))),
        outputs=(TensorSpec("text_features", FLOAT32, (None, dim)),))


def _token_graphs(files: tuple[str, str], block: Mapping[str, Any], size: int, layers: int,
                  cond: TensorSpec, length: TensorSpec) -> dict[str, GraphSpec]:
    """One generator's masked graph and (R > 1) residual graph: K logits, and K + 1 (K + 2 with the mask class)."""
    columns = block["columns"]
    graphs = {files[0]: GraphSpec(
        inputs=(TensorSpec("tokens", INT64, (None, None, columns)), cond, length),
        outputs=(TensorSpec("logits", FLOAT32, (None, None, columns, size)),))}
    if layers > 1:
        classes = size + 1 + int(bool(block.get("residual_mask_class")))
        graphs[files[1]] = GraphSpec(
            inputs=(TensorSpec("codes", INT64, (None, None, columns, layers)), TensorSpec("layer", INT64, (None,)),
                    cond, length),
            outputs=(TensorSpec("logits", FLOAT32, (None, None, columns, classes)),))
    return graphs


def _masked_graphs(manifest: Mapping[str, Any]) -> dict[str, GraphSpec]:
    """masked.onnx, residual.onnx (R > 1), each branch's pair, decoder.onnx over [B, T, C, R] maps (C: the primary
    columns plus every branch's), length.onnx (with an estimator)."""
    masked, dim = manifest["masked"], manifest["text_encoder"]["dim"]
    layers, branches = manifest["residual_layers"], masked.get("branches") or []
    cond, length = TensorSpec("cond", FLOAT32, (None, dim)), TensorSpec("length", INT64, (None,))
    graphs = {"text_encoder.onnx": _text_graph(manifest),
              **_token_graphs(("masked.onnx", "residual.onnx"), masked, manifest["codebook_size"], layers, cond,
                              length)}
    for branch in branches:
        graphs.update(_token_graphs(branch_graphs(branch["name"]), branch, branch["codebook_size"], layers, cond,
                                    length))
    if masked["length_estimator"]:
        graphs["length.onnx"] = GraphSpec(
            inputs=(cond,), outputs=(TensorSpec("logits", FLOAT32, (None, manifest["max_tokens"] + 1)),))
    columns = masked["columns"] + sum(branch["columns"] for branch in branches)
    graphs["decoder.onnx"] = GraphSpec(
        inputs=(TensorSpec("codes", INT64, (None, None, columns, layers)),),
        outputs=(TensorSpec("features", FLOAT32, (None, None, manifest["feature_dim"])),))
    return graphs


def _kv(layers: int, block: Mapping[str, Any]) -> tuple[int | None, ...]:
    """A KV cache [layers, 2, B, n_head, P, head_dim] (B and P dynamic)."""
    return (layers, 2, None, block["n_head"], None, block["head_dim"])


def _hifigpt_graphs(manifest: Mapping[str, Any]) -> dict[str, GraphSpec]:
    """temporal_step.onnx and residual_step.onnx (each with its own KV cache), decoder.onnx over [B, T, R] codes."""
    block, dim, depth = manifest["hifigpt"], manifest["text_encoder"]["dim"], manifest["residual_layers"]
    embed = block["n_head"] * block["head_dim"]
    temporal_kv, residual_kv = _kv(block["n_layer_temporal"], block), _kv(block["n_layer_residual"], block)
    temporal_inputs = [TensorSpec("cond", FLOAT32, (None, dim)), TensorSpec("codes", INT64, (None, depth)),
                       TensorSpec("position", INT64, (1,))]
    if block["length_conditioning"]:
        temporal_inputs.append(TensorSpec("length", INT64, (None,)))
    temporal_inputs.append(TensorSpec("past_kv", FLOAT32, temporal_kv))
    return {
        "text_encoder.onnx": _text_graph(manifest),
        "temporal_step.onnx": GraphSpec(
            inputs=tuple(temporal_inputs),
            outputs=(TensorSpec("context", FLOAT32, (None, embed)), TensorSpec("stop_logit", FLOAT32, (None,)),
                     TensorSpec("present_kv", FLOAT32, temporal_kv))),
        "residual_step.onnx": GraphSpec(
            inputs=(TensorSpec("context", FLOAT32, (None, embed)), TensorSpec("code", INT64, (None,)),
                    TensorSpec("depth", INT64, (1,)), TensorSpec("past_kv", FLOAT32, residual_kv)),
            outputs=(TensorSpec("logits", FLOAT32, (None, manifest["codebook_size"])),
                     TensorSpec("present_kv", FLOAT32, residual_kv))),
        "decoder.onnx": GraphSpec(
            inputs=(TensorSpec("codes", INT64, (None, None, depth)),),
            outputs=(TensorSpec("features", FLOAT32, (None, None, manifest["feature_dim"])),)),
    }


def expected_graphs(manifest: Mapping[str, Any]) -> dict[str, GraphSpec]:
    """The input/output names, types and (static where known) dims each graph must have for this manifest."""
    family = manifest.get("family", "gpt")
    if family == "masked":
        return _masked_graphs(manifest)
    if family == "hifigpt":
        return _hifigpt_graphs(manifest)
    gpt = manifest["gpt"]
    dim = manifest["text_encoder"]["dim"]
    kv = _kv(gpt["n_layer"], gpt)
    step_inputs = [TensorSpec("cond", FLOAT32, (None, dim)), TensorSpec("token", INT64, (None,)),
                   TensorSpec("position", INT64, (1,))]
    if gpt["length_conditioning"]:
        step_inputs.append(TensorSpec("length", INT64, (None,)))
    step_inputs.append(TensorSpec("past_kv", FLOAT32, kv))
    residual = manifest["residual_layers"]
    codes_shape: tuple[int | None, ...] = (None, None) if residual == 1 else (None, None, residual)
    return {
        "text_encoder.onnx": _text_graph(manifest),
        "gpt_step.onnx": GraphSpec(
            inputs=tuple(step_inputs),
            outputs=(TensorSpec("logits", FLOAT32, (None, manifest["codebook_size"] + 1)),
                     TensorSpec("present_kv", FLOAT32, kv))),
        "decoder.onnx": GraphSpec(
            inputs=(TensorSpec("codes", INT64, codes_shape),),
            outputs=(TensorSpec("features", FLOAT32, (None, None, manifest["feature_dim"])),)),
    }


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
