"""int8 dynamic quantisation: the graphs really get int8 weights, the bundle records it, and the report's numbers
(logit difference, greedy agreement, text cosine) are measured against the float32 graphs."""
from __future__ import annotations

import json

import numpy as np
import onnx
import torch

from t2m.export.graph_export import ort_session
from t2m.export.onnx_gpt import export_gpt_step
from t2m.export.parity import ort_greedy_rollout
from t2m.export.quantize import gpt_int8_report, quantize_graph, text_int8_report
from t2m.model.networks.gpt import GPTConfig, MotionGPT
from tests.export.non_vnni import ReferenceSession


def _op_types(path) -> set[str]:
    return {node.op_type for node in onnx.load(str(path)).graph.node}


def test_gpt_step_int8_is_smaller_and_close_to_float32(tmp_path):
    torch.manual_seed(0)
    gpt = MotionGPT(GPTConfig(codebook_size=64, embed=64, n_head=4, n_layer_base=2, n_layer_head=2, text_dim=32)).eval()
    fp32 = export_gpt_step(gpt, tmp_path / "gpt_step.onnx")
    int8 = quantize_graph(fp32, tmp_path / "gpt_step.int8.onnx")
    assert "MatMulInteger" in _op_types(int8) and "MatMulInteger" not in _op_types(fp32)
    c = gpt.config
    manifest = {"gpt": {"n_layer": c.n_layer, "n_head": c.n_head, "head_dim": c.head_dim, "default_guidance": 3.0},
                "max_tokens": c.max_tokens, "end_id": c.end_id, "text_encoder": {"dim": c.text_dim, "normalize": True}}
    report = gpt_int8_report(fp32, int8, manifest, steps=20)
    assert report.int8_bytes < 0.5 * report.fp32_bytes
    assert 0 < report.max_abs_logit_diff < 0.05  # the logits of this model span about +-0.5
    same = gpt_int8_report(fp32, fp32, manifest, steps=20)  # the comparison itself: zero against itself
    assert same.max_abs_logit_diff == 0 and same.greedy_codes_match


def test_int8_gpt_step_computes_the_same_on_cpus_without_vnni(tmp_path):
    """The saturating int16 pair sums of non-VNNI CPUs change nothing for our graphs (7-bit weights), while they
    do change a graph quantised with full 8-bit weights: the emulation is sensitive to the failure it guards."""
    torch.manual_seed(0)
    gpt = MotionGPT(GPTConfig(codebook_size=64, embed=64, n_head=4, n_layer_base=2, n_layer_head=2, text_dim=32)).eval()
    fp32 = export_gpt_step(gpt, tmp_path / "gpt_step.onnx")
    c = gpt.config
    rng = np.random.default_rng(0)
    cond = rng.normal(size=(2, c.text_dim)).astype(np.float32)
    cond /= np.linalg.norm(cond, axis=1, keepdims=True)
    length, shape, steps = np.array([6, 0], np.int64), (c.n_layer, c.n_head, c.head_dim), 6

    def logits(session) -> np.ndarray:
        return np.stack(ort_greedy_rollout(session, cond, length, shape, steps, c.end_id, 3.0).logits)

    ours = quantize_graph(fp32, tmp_path / "int8_7bit.onnx")
    exact, saturated = logits(ReferenceSession(ours, False)), logits(ReferenceSession(ours, True))
    np.testing.assert_array_equal(exact, saturated)
    np.testing.assert_allclose(exact, logits(ort_session(ours, threads=1)), atol=1e-4)  # the emulation is onnxruntime's
    full = quantize_graph(fp32, tmp_path / "int8_8bit.onnx", reduce_range=False)
    assert np.abs(logits(ReferenceSession(full, True)) - logits(ReferenceSession(full, False))).max() > 0.02


def test_minilm_int8_keeps_the_text_features(exported_runs, tmp_path):
    bundle, _ = exported_runs
    assert json.loads((bundle / "manifest.json").read_text())["quantization"]["text_encoder"] is None
    int8 = quantize_graph(bundle / "text_encoder.onnx", tmp_path / "text_encoder.int8.onnx")
    report = text_int8_report(bundle / "text_encoder.onnx", int8, bundle / "tokenizer.json", repeats=1)
    assert report.int8_bytes < 0.3 * report.fp32_bytes  # embeddings quantised too
    assert report.min_cosine > 0.98, report  # per-tensor scales would give ~0.955 here
    assert report.mean_cosine < 1.0  # quantisation changed something: the check is not comparing a graph to itself
