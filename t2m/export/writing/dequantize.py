"""Undo int8 dynamic quantisation in a graph: every MatMulInteger with int8 weights becomes a float MatMul on the
dequantised weights, every int8 embedding table read through Gather + DequantizeLinear becomes a float table.

Why: the shipped bundles' step graphs are int8-dynamic, the fastest rule on CPUs, but onnxruntime's CUDA provider
has no DynamicQuantizeLinear kernel, so each quantised MatMul goes to the CPU and back (measured on an H100: the
default model's int8 steps ran 2x slower than PyTorch at batch 256;
docs/measurements/gpu_suite_h100_first_device_session.log).
The float weights are the int8 ones dequantised, ``(w - zero_point) * scale``, so the model is the shipped one minus
the activation rounding; ``t2m quantize --scheme float32|fp16`` writes such a copy for GPUs and measures it.
"""
from __future__ import annotations

from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from t2m.export.writing.row_quantize import ROW_ONE, row_quantized_source

__all__ = ["dequantize_graph", "is_int8_dynamic"]


def is_int8_dynamic(model: Any) -> bool:
    """Whether the onnx model holds int8-dynamic MatMuls (the kind this module undoes)."""
    return any(node.op_type == "MatMulInteger" for node in model.graph.node)


def _dequantized(q: np.ndarray, zero_point: np.ndarray, scale: np.ndarray, axis: int) -> np.ndarray:
    """(q - zero_point) * scale with per-axis parameters broadcast along `axis` (scalars: per tensor)."""
    shape = [1] * q.ndim
    if (zero_point.ndim == 1 and zero_point.size > 1) or (scale.ndim == 1 and scale.size > 1):
        shape[axis] = -1
    return ((q.astype(np.float32) - zero_point.astype(np.float32).reshape(shape))
            * scale.astype(np.float32).reshape(shape)).astype(np.float32)


def dequantize_graph(src: str | Path, dst: str | Path) -> Path:
    """Write a float copy of the int8-dynamic graph `src` to `dst` (inputs, outputs and names unchanged); a pattern
    this module does not know is an error naming the node, never a half-converted graph."""
    import onnx
    from onnx import helper, numpy_helper

    model = onnx.load(str(src))
    graph = model.graph
    if not is_int8_dynamic(model):
        raise ValueError(f"{src}: no MatMulInteger node (not an int8-dynamic graph)")
    inits = {init.name: init for init in graph.initializer}
    producer = {out: node for node in graph.node for out in node.output}
    consumers: dict[str, list[Any]] = defaultdict(list)
    for node in graph.node:
        for name in node.input:
            consumers[name].append(node)

    def constant(name: str) -> np.ndarray:
        if name not in inits:
            raise ValueError(f"{src}: expected {name!r} to be an initializer (a quantised weight's parameter)")
        return numpy_helper.to_array(inits[name])

    def only_consumer(name: str, op_type: str, at: str) -> Any:
        found = consumers.get(name, [])
        if len(found) != 1 or found[0].op_type != op_type:
            raise ValueError(f"{src}: node {at!r}: expected its output to feed one {op_type}, found "
                             f"{[n.op_type for n in found]}")
        return found[0]

    replace: dict[int, Any] = {}         # id(node) -> its float replacement
    drop: set[int] = set()
    new_inits = []
    after: dict[int, Any] = {}            # id(node) -> a new node placed right after it (its inputs are ready there)
    for node in graph.node:
        if node.op_type == "MatMulInteger":
            x_q, w_q, x_zp, w_zp = node.input
            quantize = producer.get(x_q)
            cast = only_consumer(node.output[0], "Cast", node.name)
            rescale = only_consumer(cast.output[0], "Mul", cast.name)
            scales = producer[next(name for name in rescale.input if name != cast.output[0])]
            source = row_quantized_source(x_q)
            if source is not None:      # per row (row_quantize.py): the row scale's Mul after the rescale goes too
                x, x_scale = source, ROW_ONE
                rows = only_consumer(rescale.output[0], "Mul", rescale.name)
                drop.add(id(rescale))
                rescale = rows
            elif quantize is not None and quantize.op_type == "DynamicQuantizeLinear":
                x, x_scale = quantize.input[0], quantize.output[1]
            elif quantize is not None and quantize.op_type == "Gather" and quantize.input[0] in inits:
                # an int8 embedding table read straight into the MatMul: its rows dequantised by the table's own
                # (per-tensor) scale, the other initializer of the scales' product
                x_scale = next(name for name in scales.input if name in inits and not name.startswith(
                    w_q.removesuffix("_quantized")))
                table = _dequantized(constant(quantize.input[0]), constant(x_zp), constant(x_scale), axis=0)
                table_name, x = f"{quantize.input[0]}_dequantized", f"{quantize.output[0]}_float"
                new_inits.append(numpy_helper.from_array(table, table_name))
                after[id(quantize)] = helper.make_node("Gather", [table_name, quantize.input[1]], [x],
                                                       name=f"{quantize.name}_float",
                                                       **{a.name: a.i for a in quantize.attribute
                                                          if a.name == "axis"})
            else:
                raise ValueError(f"{src}: node {node.name!r}: expected its activations from DynamicQuantizeLinear "
                                 "or from a Gather of an int8 table")
            w_scale = next(name for name in scales.input if name != x_scale)
            weight = _dequantized(constant(w_q), constant(w_zp), constant(w_scale), axis=1)
            name = f"{w_q}_dequantized"
            new_inits.append(numpy_helper.from_array(weight, name))
            replace[id(rescale)] = helper.make_node("MatMul", [x, name], list(rescale.output),
                                                    name=f"{node.name}_float")
            drop.update({id(node), id(cast)})
        elif node.op_type == "DequantizeLinear" and node.input[0] in producer:
            gather = producer[node.input[0]]
            if gather.op_type != "Gather" or gather.input[0] not in inits:
                continue                  # activations dequantised at run time stay as they are
            table, scale = constant(gather.input[0]), constant(node.input[1])
            zero_point = constant(node.input[2]) if len(node.input) > 2 and node.input[2] else np.zeros(1, np.int8)
            if scale.size not in (1, table.shape[-1]):
                raise ValueError(f"{src}: node {node.name!r}: expected one scale or one per column of "
                                 f"{gather.input[0]!r} {list(table.shape)}, got {list(scale.shape)}")
            # per-column parameters of the table apply to it the same before or after the Gather picks rows
            weight = _dequantized(table, zero_point, scale, axis=table.ndim - 1)
            name = f"{gather.input[0]}_dequantized"
            new_inits.append(numpy_helper.from_array(weight, name))
            replace[id(node)] = helper.make_node("Gather", [name, gather.input[1]], list(node.output),
                                                 name=f"{gather.name}_float",
                                                 **{a.name: a.i for a in gather.attribute if a.name == "axis"})
            drop.add(id(gather))
    nodes = []
    for node in graph.node:
        if id(node) not in drop:
            nodes.append(replace.get(id(node), node))
        if id(node) in after:
            nodes.append(after[id(node)])
    nodes = _live(nodes, [out.name for out in graph.output])
    del graph.node[:]
    graph.node.extend(nodes)
    graph.initializer.extend(new_inits)
    used = {name for node in graph.node for name in node.input}
    kept = [init for init in graph.initializer if init.name in used]
    del graph.initializer[:]
    graph.initializer.extend(kept)
    onnx.checker.check_model(model)
    onnx.save(model, str(dst))
    return Path(dst)


def _live(nodes: list[Any], outputs: list[str]) -> list[Any]:
    """The nodes some graph output depends on, in their order (the quantisers' leftovers are dead after a rewrite)."""
    producer = {out: node for node in nodes for out in node.output}
    needed, stack = set(), list(outputs)
    while stack:
        node = producer.get(stack.pop())
        if node is not None and id(node) not in needed:
            needed.add(id(node))
            stack.extend(node.input)
    return [node for node in nodes if id(node) in needed]
