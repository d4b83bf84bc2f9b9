"""Write t2m/runtime/keep_rows.onnx, the one-node graph that keeps some rows of a device-resident key/value
cache (Gather along the batch axis 2 of [n_layer, 2, B, n_head, P, head_dim]), or check that the committed file is
current.

Why a committed file: the service has no `onnx` package at run time (only onnxruntime), yet a bound step cache
(t2m/runtime/bound_step.py) must drop finished rows without leaving the device, so the graph is built here,
with onnx, once. tests/service/test_bound_step.py fails when the committed file differs from what this writes.
Usage: python scripts/keep_rows_graph.py            (rewrite the file)
       python scripts/keep_rows_graph.py --check    (exit 1 and say so when it is not current)
"""
from __future__ import annotations

import sys
from pathlib import Path

import onnx
from onnx import TensorProto, helper

GRAPH = Path(__file__).resolve().parent.parent / "t2m" / "service" / "engine" / "keep_rows.onnx"
CACHE_DIMS = ["n_layer", "two", "batch", "n_head", "past", "head_dim"]


def build() -> bytes:
    """past float32 [n_layer, 2, B, n_head, P, head_dim], rows int64 [K] -> kept float32 [.., K, ..] (opset 13, IR 8:
    every onnxruntime the project accepts reads it)."""
    node = helper.make_node("Gather", ["past", "rows"], ["kept"], axis=2)
    graph = helper.make_graph(
        [node], "keep_rows",
        [helper.make_tensor_value_info("past", TensorProto.FLOAT, CACHE_DIMS),
         helper.make_tensor_value_info("rows", TensorProto.INT64, ["kept_rows"])],
        [helper.make_tensor_value_info("kept", TensorProto.FLOAT,
                                       [*CACHE_DIMS[:2], "kept_rows", *CACHE_DIMS[3:]])])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)], ir_version=8,
                              producer_name="t2m scripts/keep_rows_graph.py")
    onnx.checker.check_model(model)
    return model.SerializeToString()


def main(argv: list[str]) -> int:
    wanted = build()
    current = GRAPH.read_bytes() if GRAPH.is_file() else b""
    if "--check" in argv:
        if current != wanted:
            print(f"{GRAPH}: not current; run python scripts/keep_rows_graph.py", file=sys.stderr)
            return 1
        return 0
    if current != wanted:
        GRAPH.write_bytes(wanted)
    print(f"{GRAPH}: {'rewritten' if current != wanted else 'already current'} ({len(wanted)} bytes)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
