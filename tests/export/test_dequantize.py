"""Dequantising int8-dynamic graphs for GPUs (t2m/export/writing/dequantize.py, `t2m quantize --scheme float32|fp16`
on an int8 bundle): no int8 op is left, the float graph computes what the int8 weights mean without the activation
rounding, and the copies are served."""
from __future__ import annotations

import json

import numpy as np
import onnx
import pytest

from t2m.bundles import DEFAULT_BUNDLE
from t2m.export.graphs.export import ort_session
from t2m.export.writing.dequantize import dequantize_graph
from t2m.export.writing.int8 import quantize_bundle
from t2m.export.writing.quantize import quantize_graph
from t2m.families.gpt.random_bundle import build_random_bundle

INT8_OPS = {"MatMulInteger", "DynamicQuantizeLinear", "DequantizeLinear"}


def _op_types(path) -> set[str]:
    return {node.op_type for node in onnx.load(str(path)).graph.node}


def _residual_feeds(batch: int = 4) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    return {"context": rng.normal(size=(batch, 256)).astype(np.float32), "code": rng.integers(0, 256, batch),
            "depth": np.array([2]), "past_kv": rng.normal(size=(3, 2, batch, 4, 2, 64)).astype(np.float32)}


def test_the_default_step_graph_dequantised_has_no_int8_op_and_keeps_its_logits(tmp_path):
    src = DEFAULT_BUNDLE / "residual_step.onnx"
    dst = dequantize_graph(src, tmp_path / "residual_step.onnx")
    assert "MatMulInteger" in _op_types(src) and not _op_types(dst) & INT8_OPS
    feeds = _residual_feeds()
    (int8_logits, int8_cache), (logits, cache) = (ort_session(path).run(None, feeds) for path in (src, dst))
    assert logits.shape == int8_logits.shape and cache.shape == int8_cache.shape
    # the same weights; only the int8 graph's 7-bit activation rounding differs
    assert np.abs(logits - int8_logits).max() < 0.1 * np.abs(int8_logits).max()
    assert (logits.argmax(-1) == int8_logits.argmax(-1)).mean() >= 0.75


def test_dequantised_is_closer_to_float32_than_int8_and_a_float_graph_is_refused(tmp_path):
    bundle = build_random_bundle(tmp_path / "fp32", codebook_size=16, embed=32, n_head=2, n_layer=2)
    float_graph = bundle / "gpt_step.onnx"
    int8 = quantize_graph(float_graph, tmp_path / "int8.onnx")
    dequantised = dequantize_graph(int8, tmp_path / "dequantised.onnx")
    session = ort_session(float_graph)
    rng = np.random.default_rng(1)
    feeds = {}
    for arg in session.get_inputs():
        shape = [2 if isinstance(d, str) and d == "batch" else 3 if isinstance(d, str) else d for d in arg.shape]
        feeds[arg.name] = (rng.integers(0, 8, shape) if "int" in arg.type else
                           rng.normal(size=shape).astype(np.float32))
    reference, quantised, undone = (ort_session(p).run(None, feeds)[0] for p in (float_graph, int8, dequantised))
    assert np.abs(undone - reference).max() < np.abs(quantised - reference).max()
    assert not np.array_equal(undone, reference)        # the weights keep their int8 rounding
    with pytest.raises(ValueError, match="no MatMulInteger"):
        dequantize_graph(float_graph, tmp_path / "x.onnx")


def test_an_int8_bundle_gets_float32_and_fp16_copies_and_a_float_one_is_refused(tmp_path):
    from t2m.runtime.engine import OnnxEngine
    from t2m.runtime.types import GenerationRequest, SegmentRequest

    src = build_random_bundle(tmp_path / "fp32", codebook_size=16, embed=32, n_head=2, n_layer=2)
    quantize_bundle(src, tmp_path / "int8", scheme="int8", parity=False)
    request = GenerationRequest(segments=[SegmentRequest("a person walks", 1.0)], seed=3, guidance=3.0)
    for scheme, label in (("float32", "float32-dequantized"), ("fp16", "fp16")):
        manifest, report = quantize_bundle(tmp_path / "int8", tmp_path / scheme, scheme=scheme, runs=2)
        assert manifest["quantization"]["gpt_step"] == label and report is not None and report["tokens"] > 0
        assert not _op_types(tmp_path / scheme / "gpt_step.onnx") & INT8_OPS
        assert "vs the int8 bundle" in (tmp_path / scheme / "MODEL_CARD.md").read_text()
        motion = OnnxEngine.load(tmp_path / scheme, intra_op_threads=1).generate(request)
        assert np.isfinite(motion.joints).all()
    written = json.loads((tmp_path / "int8" / "manifest.json").read_text())
    assert written["quantization"]["gpt_step"] == "int8-dynamic-rows"
    with pytest.raises(ValueError, match="dequantises int8-dynamic graphs"):
        quantize_bundle(src, tmp_path / "again", scheme="float32", parity=False)


def test_the_masked_graph_with_an_int8_table_read_into_a_matmul_is_dequantised(tmp_path):
    """The masked family's int8 graph feeds a Gather of its int8 token table straight into a MatMulInteger (no
    DynamicQuantizeLinear): the table's rows are dequantised by the table's own scale, the logits kept."""
    from t2m.bundles import EMBEDDED_BUNDLES

    bundle = EMBEDDED_BUNDLES["masked"]
    manifest = json.loads((bundle / "manifest.json").read_text())
    src = bundle / "masked.onnx"
    dst = dequantize_graph(src, tmp_path / "masked.onnx")
    assert not _op_types(dst) & INT8_OPS
    rng = np.random.default_rng(2)
    columns, codebook = manifest["masked"]["columns"], manifest["codebook_size"]
    feeds = {"tokens": rng.integers(0, codebook, (2, 10, columns)),
             "cond": rng.normal(size=(2, manifest["text_encoder"]["dim"])).astype(np.float32) * 0.05,
             "length": np.array([10, 7])}
    int8_logits, logits = (ort_session(path).run(None, feeds)[0] for path in (src, dst))
    assert np.abs(logits - int8_logits).max() < 0.1 * np.abs(int8_logits).max()
    assert (logits.argmax(-1) == int8_logits.argmax(-1)).mean() >= 0.75
