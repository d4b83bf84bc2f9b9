"""int8 dynamic quantisation: the graphs really get int8 weights, the bundle records it, and the report's numbers
(logit difference, greedy agreement, text cosine) are measured against the float32 graphs. The opt-in int4 step
(`t2m quantize --scheme int4`): MatMulNBits weights, close to float32, a wrongly scaled copy caught."""
from __future__ import annotations

import json

import numpy as np
import onnx
import pytest
import torch

from t2m.export.graphs.export import ort_session
from t2m.export.writing.int8 import quantize_bundle_gpt
from t2m.export.writing.quantize import quantize_graph, quantize_graph_int4, text_int8_report
from t2m.families.gpt.export_graphs import export_gpt_step
from t2m.families.gpt.network import GPTConfig, MotionGPT
from t2m.families.gpt.parity import GptInt8Report, gpt_int8_report, ort_greedy_rollout
from t2m.families.gpt.random_bundle import build_random_bundle
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


def _parity_holds(report: GptInt8Report) -> bool:
    """What shipping an int8 step graph asks of it on a greedy rollout: the same codes, logits close."""
    return report.greedy_codes_match and report.max_abs_logit_diff < 0.05


def _double_one_layers_weights(src, dst) -> str:
    """A wrongly quantised graph: one transformer layer's MatMulInteger int8 weights doubled (8-bit values read with
    the 7-bit scale, the kind of slip a changed quantiser makes); returns the weight's name. The condition
    embedding is not the one: doubling a unit-norm condition's projection moves the logits too little to matter
    (0.019 here with onnxruntime 1.32, whose quantiser lists that MatMul first)."""
    model = onnx.load(str(src))
    weights = {init.name: init for init in model.graph.initializer}
    name = next(node.input[1] for node in model.graph.node
                if node.op_type == "MatMulInteger" and "cond_emb" not in node.input[1])
    doubled = onnx.numpy_helper.to_array(weights[name]).astype(np.int16) * 2
    weights[name].CopyFrom(onnx.numpy_helper.from_array(doubled.clip(-128, 127).astype(np.int8), name))
    onnx.save(model, str(dst))
    return name


def test_int8_parity_passes_the_quantised_graph_and_fails_a_wrong_one(tmp_path):
    """The parity check that ships int8 step graphs holds for quantize_graph's output and fails for the same graph
    with one layer wrongly quantised (the control: the check can fail)."""
    torch.manual_seed(1)
    gpt = MotionGPT(GPTConfig(codebook_size=64, embed=64, n_head=4, n_layer_base=2, n_layer_head=2, text_dim=32)).eval()
    fp32 = export_gpt_step(gpt, tmp_path / "gpt_step.onnx")
    int8 = quantize_graph(fp32, tmp_path / "gpt_step.int8.onnx")
    c = gpt.config
    manifest = {"gpt": {"n_layer": c.n_layer, "n_head": c.n_head, "head_dim": c.head_dim, "default_guidance": 3.0},
                "max_tokens": c.max_tokens, "end_id": c.end_id, "text_encoder": {"dim": c.text_dim, "normalize": True}}
    assert _parity_holds(gpt_int8_report(fp32, int8, manifest, steps=20))
    _double_one_layers_weights(int8, tmp_path / "wrong.onnx")
    wrong = gpt_int8_report(fp32, tmp_path / "wrong.onnx", manifest, steps=20)
    assert not _parity_holds(wrong), wrong


def test_int8_bundle_copy_is_verified_and_served_like_its_float32_original(tmp_path):
    from t2m.runtime.engine import OnnxEngine
    from t2m.runtime.types import GenerationRequest, SegmentRequest

    src = build_random_bundle(tmp_path / "fp32", codebook_size=16, embed=32, n_head=2, n_layer=2)
    manifest = quantize_bundle_gpt(src, tmp_path / "int8", version="0.0.1")
    assert manifest["quantization"]["gpt_step"] == "int8-dynamic-rows" and manifest["version"] == "0.0.1"
    assert "MatMulInteger" in _op_types(tmp_path / "int8" / "gpt_step.onnx")
    original = json.loads((src / "manifest.json").read_text())
    changed = {name for name in original["files"] if original["files"][name] != manifest["files"][name]}
    assert changed == {"gpt_step.onnx"}
    report = gpt_int8_report(src / "gpt_step.onnx", tmp_path / "int8" / "gpt_step.onnx", original, steps=10)
    assert _parity_holds(report) and report.max_abs_logit_diff > 0   # quantised, and close
    request = GenerationRequest(segments=[SegmentRequest("a person walks", 1.0)], seed=3, guidance=3.0)
    motion = OnnxEngine.load(tmp_path / "int8", intra_op_threads=1).generate(request)
    assert motion.joints.shape[0] == 20 and np.isfinite(motion.joints).all()
    with pytest.raises(ValueError, match="already int8-dynamic-rows"):
        quantize_bundle_gpt(tmp_path / "int8", tmp_path / "twice")


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

    for per_row in (False, True):    # activations per tensor (text encoders) and per row (the token graphs)
        ours = quantize_graph(fp32, tmp_path / f"int8_7bit_{per_row}.onnx", per_row=per_row)
        exact, saturated = logits(ReferenceSession(ours, False)), logits(ReferenceSession(ours, True))
        np.testing.assert_array_equal(exact, saturated)
        np.testing.assert_allclose(exact, logits(ort_session(ours, threads=1)), atol=1e-4)  # the emulation is ort's
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


INT4_MAX_LOGIT_DIFF = 0.15   # int4 with int8 compute on these random GPTs: 0.07-0.10 (logits span about +-0.5)


def _small_gpt_and_manifest(seed: int, embed: int = 128) -> tuple[MotionGPT, dict]:
    torch.manual_seed(seed)
    gpt = MotionGPT(GPTConfig(codebook_size=64, embed=embed, n_head=4, n_layer_base=2, n_layer_head=2,
                              text_dim=32)).eval()
    c = gpt.config
    return gpt, {"gpt": {"n_layer": c.n_layer, "n_head": c.n_head, "head_dim": c.head_dim, "default_guidance": 3.0},
                 "max_tokens": c.max_tokens, "end_id": c.end_id,
                 "text_encoder": {"dim": c.text_dim, "normalize": True}}


def _scale_every_int4_block(src, dst, factor: float) -> None:
    """A wrongly quantised int4 graph: every MatMulNBits scale multiplied (15 / 7: scales computed for 3-bit instead
    of 4-bit values, the kind of slip a changed bit width makes)."""
    model = onnx.load(str(src))
    weights = {init.name: init for init in model.graph.initializer}
    for node in model.graph.node:
        if node.op_type == "MatMulNBits":
            scales = onnx.numpy_helper.to_array(weights[node.input[2]]) * factor
            weights[node.input[2]].CopyFrom(onnx.numpy_helper.from_array(scales.astype(np.float32), node.input[2]))
    onnx.save(model, str(dst))


def test_int4_step_is_smaller_close_to_float32_and_a_wrongly_scaled_copy_is_caught(tmp_path):
    """Greedy codes may part earlier than int8's (random weights have flat logits), so what is compared is the
    logits while the codes agree: within INT4_MAX_LOGIT_DIFF, and far outside it for the control."""
    gpt, manifest = _small_gpt_and_manifest(seed=0)
    fp32 = export_gpt_step(gpt, tmp_path / "gpt_step.onnx")
    int4 = quantize_graph_int4(fp32, tmp_path / "gpt_step.int4.onnx")
    assert "MatMulNBits" in _op_types(int4) and "MatMulNBits" not in _op_types(fp32)
    report = gpt_int8_report(fp32, int4, manifest, steps=20)
    assert report.int8_bytes < 0.2 * report.fp32_bytes
    assert 0 < report.max_abs_logit_diff < INT4_MAX_LOGIT_DIFF
    _scale_every_int4_block(int4, tmp_path / "wrong.onnx", 15 / 7)
    wrong = gpt_int8_report(fp32, tmp_path / "wrong.onnx", manifest, steps=20)
    assert wrong.max_abs_logit_diff > 2 * INT4_MAX_LOGIT_DIFF, wrong


def test_quantize_cli_writes_a_served_int4_copy_and_refuses_what_it_cannot_do(tmp_path, capsys):
    from t2m.cli.main import main
    from t2m.runtime.engine import OnnxEngine
    from t2m.runtime.types import GenerationRequest, SegmentRequest

    src = build_random_bundle(tmp_path / "fp32", codebook_size=16, embed=32, n_head=2, n_layer=2)
    assert main(["quantize", str(src), "-o", str(tmp_path / "int4"), "--scheme", "int4", "--version", "0.0.2"]) == 0
    manifest = json.loads((tmp_path / "int4" / "manifest.json").read_text())
    assert manifest["quantization"]["gpt_step"] == "int4-matmulnbits" and manifest["version"] == "0.0.2"
    assert "MatMulNBits" in _op_types(tmp_path / "int4" / "gpt_step.onnx")
    request = GenerationRequest(segments=[SegmentRequest("a person walks", 1.0)], seed=3, guidance=3.0)
    motion = OnnxEngine.load(tmp_path / "int4", intra_op_threads=1).generate(request)
    assert motion.joints.shape[0] == 20 and np.isfinite(motion.joints).all()
    capsys.readouterr()
    for argv, message in (
        ([str(tmp_path / "int4"), "-o", str(tmp_path / "twice"), "--scheme", "int4"], "already int4-matmulnbits"),
        ([str(tmp_path / "none"), "-o", str(tmp_path / "x")], "no manifest.json"),
        ([str(src), "-o", str(src)], "-o must differ"),
    ):
        assert main(["quantize", *argv]) == 2
        err = capsys.readouterr().err.strip()
        assert message in err and len(err.splitlines()) == 1
