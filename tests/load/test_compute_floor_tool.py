"""t2m/bench/compute_floor.py counts a graph's multiply-adds from onnxruntime's profile: checked on graphs whose
count is known by hand, float32 and per-row int8, and its report runs on the embedded masked bundle."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper

from t2m.bench.compute_floor import graph_macs, main, request_calls
from t2m.export.writing.quantize import quantize_graph

MASKED = "t2m/bundles/masked"


def _graph(path) -> None:
    """x [batch, tokens, 8] -> MatMul 8x16 -> [batch, 16, tokens] -> Conv1d 16->4, kernel 3, padding 1."""
    rng = np.random.default_rng(0)
    nodes = [helper.make_node("MatMul", ["x", "w"], ["h"]), helper.make_node("Transpose", ["h"], ["t"], perm=[0, 2, 1]),
             helper.make_node("Conv", ["t", "k"], ["y"], pads=[1, 1])]
    graph = helper.make_graph(
        nodes, "known", [helper.make_tensor_value_info("x", TensorProto.FLOAT, ["batch", "tokens", 8])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, ["batch", 4, "tokens"])],
        [onnx.numpy_helper.from_array(rng.standard_normal((8, 16)).astype(np.float32), "w"),
         onnx.numpy_helper.from_array(rng.standard_normal((4, 16, 3)).astype(np.float32), "k")])
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)]), path)


def test_multiply_adds_are_counted_from_the_shapes(tmp_path):
    path = tmp_path / "known.onnx"
    _graph(path)
    batch, tokens = 2, 5
    want = batch * tokens * 16 * 8 + batch * 4 * tokens * 16 * 3
    assert graph_macs(path, batch, tokens) == want
    int8 = quantize_graph(path, tmp_path / "known_int8.onnx", per_row=True)   # the MatMul becomes integer
    assert graph_macs(int8, batch, tokens) == want


def test_the_report_runs_on_the_embedded_masked_bundle(capsys):
    manifest = json.loads(Path(MASKED, "manifest.json").read_text())
    calls = {call.graph: (call.calls, call.batch) for call in request_calls(manifest)}
    assert calls["masked.onnx"] == (manifest["masked"]["steps"], 2)
    assert calls["residual.onnx"] == (manifest["residual_layers"] - 1, 2)
    assert main(["--bundle", MASKED, "--threads", "1", "--repeats", "1"]) == 0
    out = capsys.readouterr().out
    assert "floor on 1 thread(s)" in out and "| masked.onnx | 10 | 2 |" in out


def test_a_bundle_of_another_family_is_refused_in_one_line(capsys):
    with pytest.raises(SystemExit) as stopped:
        main(["--bundle", "t2m/bundles/default"])
    assert stopped.value.code == 2 and "masked family only" in capsys.readouterr().err
