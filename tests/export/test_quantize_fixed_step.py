"""`t2m quantize --scheme fp16` and the step that T2M_CUDA_GRAPHS replays (gpt_step_fixed.onnx): fp16 converts it
beside gpt_step.onnx and measures it as served with CUDA graphs asked for (on the CPU provider here), int8 and int4
leave it float32. Why: fp16 was the faster replayed step on an H100 (docs/gpu.md), and a converted graph that nobody
measured would be served on trust."""
from __future__ import annotations

import filecmp
import json

import numpy as np
import onnx
import pytest

from t2m.export.graphs.capture_check import capture_blockers
from t2m.export.writing.bundle_parity import compare_bundles
from t2m.export.writing.int8 import quantize_bundle
from t2m.families.gpt.random_bundle import build_random_bundle

FIXED = "gpt_step_fixed.onnx"


@pytest.fixture(scope="module")
def fixed_bundle(tmp_path_factory):
    return build_random_bundle(tmp_path_factory.mktemp("fixed") / "fp32", codebook_size=16, embed=32, n_head=2,
                               n_layer=2, fixed_step=True)


def _initializer_types(path) -> set[int]:
    return {tensor.data_type for tensor in onnx.load(str(path)).graph.initializer}


def test_fp16_converts_the_replayed_step_and_measures_it_as_served(fixed_bundle, tmp_path):
    from t2m.runtime.engine import OnnxEngine
    from t2m.runtime.execution import Execution
    from t2m.runtime.types import GenerationRequest, SegmentRequest

    out = tmp_path / "fp16"
    manifest, report = quantize_bundle(fixed_bundle, out, scheme="fp16", runs=2)
    assert manifest["quantization"]["gpt_step"] == manifest["quantization"]["gpt_step_fixed"] == "fp16"
    assert onnx.TensorProto.FLOAT16 in _initializer_types(out / FIXED)
    assert onnx.TensorProto.FLOAT16 not in _initializer_types(fixed_bundle / FIXED)
    # the converter's Casts leave nothing that onnxruntime would copy between host and device inside a run
    assert capture_blockers(out / FIXED) == capture_blockers(fixed_bundle / FIXED) == []
    replayed = report["captured"][FIXED]
    graph = replayed["graphs"][FIXED]
    assert graph["calls"] > 0 and replayed["tokens"] > 0
    # half precision moves the logits a little, never far
    assert 0 < graph["max_abs_logit_diff"] < 0.05 * graph["max_abs_logit"]
    assert replayed["agreement"] >= 0.8
    assert f"`{FIXED}` (the step T2M_CUDA_GRAPHS replays on a GPU) is fp16 too" in (out / "MODEL_CARD.md").read_text()
    engine = OnnxEngine.load(out, intra_op_threads=1, execution=Execution(cuda_graphs=True))
    assert type(engine.codes.step).__name__ == "FixedCacheGptStep"
    motion = engine.generate(GenerationRequest([SegmentRequest("a person walks", 1.5)], seed=2, guidance=3.0))
    assert np.isfinite(motion.joints).all()


def test_the_replayed_step_against_itself_is_exact(fixed_bundle):
    """The measurement can tell: the same graph on both sides gives no difference at all, and every token."""
    report = compare_bundles(fixed_bundle, fixed_bundle, [FIXED], runs=2, captured=True)
    graph = report.graphs[FIXED]
    assert graph.calls > 0 and graph.max_abs_logit_diff == 0.0 and report.agreement == 1.0


def test_int8_and_int4_leave_the_replayed_step_float32(fixed_bundle, tmp_path):
    for scheme in ("int8", "int4"):
        manifest, _ = quantize_bundle(fixed_bundle, tmp_path / scheme, scheme=scheme, parity=False)
        assert "gpt_step_fixed" not in manifest["quantization"]
        assert filecmp.cmp(fixed_bundle / FIXED, tmp_path / scheme / FIXED, shallow=False)
    # an int8 bundle's fp16 copy: gpt_step dequantised first, the float32 fixed step converted as it is
    manifest, report = quantize_bundle(tmp_path / "int8", tmp_path / "from-int8", scheme="fp16", runs=1)
    assert manifest["quantization"]["gpt_step_fixed"] == "fp16" and FIXED in report["captured"]
    assert json.loads((tmp_path / "from-int8" / "manifest.json").read_text())["files"][FIXED]
