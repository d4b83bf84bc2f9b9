"""onnxruntime's int8 MatMul as a CPU without VNNI computes it, in numpy, for graphs run by onnx's reference evaluator.

On AVX2 without VNNI, the u8s8 kernel multiplies uint8 activations by int8 weights and adds adjacent pairs of
products into int16 with saturation (VPMADDUBSW) before widening to int32; with VNNI the sums are exact. The tests
cannot choose the CPU they run on, so they run the quantised graph both ways here.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
from onnx.reference import ReferenceEvaluator
from onnx.reference.op_run import OpRun


def _matmul_integer(a: np.ndarray, b: np.ndarray, a_zero_point: np.ndarray | None, saturate: bool) -> np.ndarray:
    """Y = (A - a_zp) @ B for int8 weights with zero point 0, as raw A @ B minus a_zp * column sums of B."""
    k = a.shape[-1]
    rows = a.reshape(-1, k).astype(np.int64)
    b = b.astype(np.int64)
    if k % 2:
        rows, b = np.pad(rows, ((0, 0), (0, 1))), np.pad(b, ((0, 1), (0, 0)))
    if saturate:
        pairs = rows[:, 0::2, None] * b[None, 0::2] + rows[:, 1::2, None] * b[None, 1::2]
        raw = np.clip(pairs, -32768, 32767).sum(axis=1)
    else:
        raw = rows @ b
    zero_point = np.int64(a_zero_point) if a_zero_point is not None else 0
    return (raw - zero_point * b.sum(axis=0)).reshape(*a.shape[:-1], b.shape[1]).astype(np.int32)


def _matmul_integer_op(saturate: bool) -> type[OpRun]:
    class MatMulInteger(OpRun):
        op_domain = ""

        def _run(self, a, b, a_zero_point=None, b_zero_point=None):
            assert b_zero_point is None or not np.any(b_zero_point), "int8 weights are symmetric"
            return (_matmul_integer(a, b, a_zero_point, saturate),)

    return MatMulInteger


class ReferenceSession:
    """The slice of onnxruntime.InferenceSession that export.parity's rollouts use, on onnx's reference evaluator."""

    def __init__(self, path: str | Path, saturate: bool) -> None:
        model = onnx.load(str(path))
        for opset in model.opset_import:  # the reference evaluator implements DequantizeLinear from opset 19 on
            if opset.domain in ("", "ai.onnx"):
                opset.version = max(opset.version, 19)
        self._names = [i.name for i in model.graph.input]
        self._evaluator = ReferenceEvaluator(model, new_ops=[_matmul_integer_op(saturate)])

    def get_inputs(self) -> list:
        return [type("Input", (), {"name": name})() for name in self._names]

    def run(self, output_names, feeds):
        return self._evaluator.run(output_names, feeds)
