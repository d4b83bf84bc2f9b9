"""Activations quantised per row instead of per tensor in an int8-dynamic graph, so that a row's result never
depends on the other rows of its batch.

Why: onnxruntime's dynamic quantisation (DynamicQuantizeLinear) gives a whole activation tensor one scale and zero
point, taken from its minimum and maximum over every row. In a step graph the rows are other requests (and a
request's guidance rows), so with it a request's logits, hence its motion, changed with whatever was batched beside
it (the default 0.3.0: joints up to 1.4 m apart for the same seed alone and in a batch of four), which breaks the
service's "same seed, same motion under any schedule". Here each row (the last axis: one token's features) gets its
own scale, symmetric around a fixed zero point of 128, so the quantised matrix product of a row reads only that row:

    scale = max(|x_row|) / 127,  q = round(x / scale) + 128 in [1, 255],  y = (q - 128) @ w_q * scale * w_scale

The weights, their scales and the MatMulInteger arithmetic are unchanged (7-bit weights keep onnxruntime's integer
sums exact on every x86 CPU: 2 x 255 x 63 < 32767, see quantize.quantize_graph). Per row and symmetric has the same
255 levels per row as before but spends them on one row's range rather than the batch's. The row scale multiplies
each product after the MatMul's own rescale: onnxruntime fuses MatMulInteger + Cast + Mul into MatMulIntegerToFloat,
which reads an activation scale per tensor or per column only (a per-row scale there gave logits 3-12 off).
"""
from __future__ import annotations

from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["ROW_ONE", "ROW_ZERO_POINT", "is_row_quantized", "row_quantize_graph", "row_quantized_source"]

ROW_ZERO_POINT = 128
_SUFFIX = "_rowq"        # names of the nodes and values this module adds end with it (dequantize.py finds x by it)
ROW_ONE = f"one{_SUFFIX}"   # the activation scale left in a MatMul's scale product (the row scale comes after)


def is_row_quantized(model: Any) -> bool:
    """Whether the onnx model's activations are quantised per row (written by this module)."""
    return any(node.op_type == "MatMulInteger" and node.input[0].endswith(f"{_SUFFIX}_q") for node in model.graph.node)


def row_quantized_source(name: str) -> str | None:
    """The float activation a per-row quantised input `name` was made from, or None when `name` is not one."""
    suffix = f"{_SUFFIX}_q"
    return name.removesuffix(suffix) if name.endswith(suffix) else None


def row_quantize_graph(src: str | Path, dst: str | Path) -> Path:
    """Write `src` (int8-dynamic: DynamicQuantizeLinear -> MatMulInteger) to `dst` with every DynamicQuantizeLinear
    replaced by a per-row quantisation; inputs, outputs and weights unchanged. A DynamicQuantizeLinear feeding
    anything but MatMulIntegers and their scale products is an error naming the node."""
    import onnx
    from onnx import helper, numpy_helper

    model = onnx.load(str(src))
    graph = model.graph
    quantizers = [node for node in graph.node if node.op_type == "DynamicQuantizeLinear"]
    if not quantizers:
        raise ValueError(f"{src}: no DynamicQuantizeLinear node (not an int8-dynamic graph, or already per row)")
    consumers: dict[str, list[Any]] = defaultdict(list)
    for node in graph.node:
        for name in node.input:
            consumers[name].append(node)
    constants = [numpy_helper.from_array(np.asarray(value, dtype), name) for name, value, dtype in (
        (f"zero_point{_SUFFIX}", ROW_ZERO_POINT, np.uint8), (f"levels{_SUFFIX}", 1.0 / 127.0, np.float32),
        (f"tiny{_SUFFIX}", np.finfo(np.float32).tiny, np.float32), (ROW_ONE, 1.0, np.float32))]
    zero_point, levels, tiny, one = (c.name for c in constants)
    before: dict[int, list[Any]] = {}       # id(DynamicQuantizeLinear) -> the nodes that replace it
    after: dict[int, Any] = {}              # id(a rescaling Mul) -> the per-row Mul placed after it
    for node in quantizers:
        x = node.input[0]
        x_q, x_scale, x_zp = node.output
        for user in consumers[x_q]:
            if user.op_type != "MatMulInteger" or user.input[0] != x_q or user.input[2] != x_zp:
                raise ValueError(f"{src}: node {node.name!r}: expected its output to feed MatMulIntegers as their "
                                 f"activations, found {user.op_type} {user.name!r}")
        for product in consumers[x_scale]:   # x_scale * w_scale -> the MatMul's rescale: per row after it instead
            rescales = consumers[product.output[0]]
            if product.op_type != "Mul" or len(rescales) != 1 or rescales[0].op_type != "Mul":
                raise ValueError(f"{src}: node {node.name!r}: expected its scale to feed a Mul by the weights' "
                                 f"scales and that a Mul rescaling a MatMulInteger, found {product.op_type} "
                                 f"{product.name!r}")
            product.input[list(product.input).index(x_scale)] = one
            rescale = rescales[0]
            out = rescale.output[0]
            rescale.output[0] = f"{out}{_SUFFIX}_columns"
            after[id(rescale)] = helper.make_node("Mul", [rescale.output[0], x_scale], [out],
                                                  name=f"{out}{_SUFFIX}_rows")
        stem = f"{x}{_SUFFIX}"
        ops: list[tuple[str, list[str], str, dict[str, Any]]] = [
            ("Abs", [x], f"{stem}_abs", {}),
            ("ReduceMax", [f"{stem}_abs"], f"{stem}_max", {"axes": [-1], "keepdims": 1}),
            ("Mul", [f"{stem}_max", levels], f"{stem}_step", {}),
            ("Max", [f"{stem}_step", tiny], x_scale, {}),          # an all-zero row: any scale, all codes 128
            ("Div", [x, x_scale], f"{stem}_ratio", {}),
            # round half to even, + 128, to uint8 in one node (the ratio is within +-127: nothing saturates)
            ("QuantizeLinear", [f"{stem}_ratio", one, zero_point], f"{stem}_q", {}),
        ]
        before[id(node)] = [helper.make_node(op, inputs, [out], name=f"{out}_node", **attrs)
                            for op, inputs, out, attrs in ops]
        for user in consumers[x_q]:
            user.input[0], user.input[2] = f"{stem}_q", zero_point
    nodes = []
    for node in graph.node:
        nodes.extend(before.get(id(node), [node]))
        if id(node) in after:
            nodes.append(after[id(node)])
    del graph.node[:]
    graph.node.extend(nodes)
    graph.initializer.extend(constants)
    onnx.checker.check_model(model)
    onnx.save(model, str(dst))
    return Path(dst)
