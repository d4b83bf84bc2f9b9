"""int8 activations quantised per row (t2m/export/writing/row_quantize.py): a row's result is the same whatever
else is in its batch, which per-tensor quantisation does not give; the rewrite keeps the weights (dequantising either
graph gives the same float graph), and the shipped bundles are per row."""
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
from t2m.export.writing.row_quantize import is_row_quantized, row_quantize_graph
from t2m.families.gpt.random_bundle import build_random_bundle


def _gpt_feeds(session, batch: int, seed: int = 1) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    feeds = {}
    for arg in session.get_inputs():
        shape = [batch if d == "batch" else 3 if isinstance(d, str) else d for d in arg.shape]
        feeds[arg.name] = (rng.integers(0, 8, shape) if "int" in arg.type else
                           rng.normal(size=shape).astype(np.float32) * (1 + 20 * (arg.name == "cond")))
    return feeds


def _rows(feeds: dict[str, np.ndarray], keep: slice) -> dict[str, np.ndarray]:
    """The feeds of a batch's rows `keep` (past_kv: batch on axis 2; position: shared)."""
    return {name: (value[:, :, keep] if name == "past_kv" else value if name == "position" else value[keep])
            for name, value in feeds.items()}


@pytest.fixture(scope="module")
def graphs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("rows")
    bundle = build_random_bundle(tmp / "fp32", codebook_size=16, embed=32, n_head=2, n_layer=2)
    tensor = quantize_graph(bundle / "gpt_step.onnx", tmp / "tensor.onnx")
    return {"float": bundle / "gpt_step.onnx", "tensor": tensor,
            "rows": row_quantize_graph(tensor, tmp / "rows.onnx"),
            "fresh": quantize_graph(bundle / "gpt_step.onnx", tmp / "fresh.onnx", per_row=True)}


def test_a_rows_logits_do_not_depend_on_its_batch_per_row_but_do_per_tensor(graphs):
    session = ort_session(graphs["float"])
    feeds = _gpt_feeds(session, batch=6)    # rows of very different scales (cond x 21 on half the draws)
    for kind, differs in (("rows", False), ("fresh", False), ("tensor", True)):
        step = ort_session(graphs[kind])
        batched = step.run(["logits"], feeds)[0]
        alone = np.concatenate([step.run(["logits"], _rows(feeds, slice(i, i + 1)))[0] for i in range(6)])
        assert (not np.array_equal(batched, alone)) == differs, kind


def test_the_rewrite_keeps_the_weights_and_stays_close_to_float(graphs, tmp_path):
    assert is_row_quantized(onnx.load(str(graphs["rows"]))) and not is_row_quantized(onnx.load(str(graphs["tensor"])))
    feeds = _gpt_feeds(ort_session(graphs["float"]), batch=4)
    undone = [ort_session(dequantize_graph(graphs[kind], tmp_path / f"{kind}.onnx")).run(["logits"], feeds)[0]
              for kind in ("rows", "tensor")]
    np.testing.assert_array_equal(undone[0], undone[1])
    reference, rows = (ort_session(graphs[kind]).run(["logits"], feeds)[0] for kind in ("float", "rows"))
    assert np.abs(rows - reference).max() < 0.1 * np.abs(reference).max()
    with pytest.raises(ValueError, match="no DynamicQuantizeLinear"):
        row_quantize_graph(graphs["rows"], tmp_path / "twice.onnx")


def test_an_int8_bundle_per_tensor_is_rewritten_per_row_and_not_twice(tmp_path):
    src = build_random_bundle(tmp_path / "fp32", codebook_size=16, embed=32, n_head=2, n_layer=2)
    quantize_bundle(src, tmp_path / "int8", scheme="int8", parity=False)
    manifest = json.loads((tmp_path / "int8" / "manifest.json").read_text())
    assert manifest["quantization"]["gpt_step"] == "int8-dynamic-rows"
    with pytest.raises(ValueError, match="already int8-dynamic-rows"):
        quantize_bundle(tmp_path / "int8", tmp_path / "again", scheme="int8", parity=False)


@pytest.mark.parametrize("name", ["default", "both", "masked"])
def test_the_shipped_int8_token_graphs_are_per_row(name):
    manifest = json.loads((DEFAULT_BUNDLE.parent / name / "manifest.json").read_text())
    token_graphs = {graph: label for graph, label in manifest["quantization"].items() if graph != "text_encoder"}
    assert token_graphs and set(token_graphs.values()) == {"int8-dynamic-rows"}
    for graph in token_graphs:
        assert is_row_quantized(onnx.load(str(DEFAULT_BUNDLE.parent / name / f"{graph}.onnx")))


@pytest.mark.parametrize("name", ["default", "masked"])
def test_a_shipped_models_request_is_the_same_alone_and_in_a_batch(name):
    """The bug per-tensor activations had: the default 0.3.0 moved a request's joints by up to 1.4 m, the masked
    0.2.0 by up to 1.8 m."""
    from t2m.runtime.engine import OnnxEngine
    from t2m.runtime.types import GenerationRequest, SegmentRequest

    engine = OnnxEngine.load(DEFAULT_BUNDLE.parent / name, intra_op_threads=1)
    texts = ["a person walks forward", "a person jumps high", "someone kicks with the right leg", "a person waves"]
    requests = [GenerationRequest([SegmentRequest(texts[i % 4], 1.0 + i % 3)], seed=i, guidance=3.0)
                for i in range(8)]
    batched = engine.generate_batch(requests)
    for request, motion in zip(requests[:3], batched):
        np.testing.assert_array_equal(motion.joints, engine.generate(request).joints)
