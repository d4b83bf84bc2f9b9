"""T2M_CUDA_GRAPHS in the service: the masked family's token graphs are opened to be replayed as CUDA graphs and
its steps call them through GraphedSession. Here on the CPU provider (the same buffers, no capture; onnxruntime's
CPU provider ignores graph ids), which is how their numbers are checked: a seed gives the plain engine's motion.
On an H100 the same graphs were captured and gave the plain calls' codes (docs/measurements/
gpu_suite_h100_second_device_session.log)."""
from __future__ import annotations

import dataclasses
import logging

import numpy as np
import pytest
from pydantic import ValidationError

from t2m.runtime.engine import OnnxEngine
from t2m.runtime.execution import Execution
from t2m.runtime.types import GenerationRequest, SegmentRequest
from t2m.service.settings import Settings

REQUEST = GenerationRequest([SegmentRequest("a person walks forward", 2.0), SegmentRequest("a person bows", 1.5)],
                            seed=11, guidance=3.0)


def test_the_replayed_graphs_give_the_plain_engines_motion(masked_model):
    plain = OnnxEngine.load(masked_model, intra_op_threads=1)
    replayed = OnnxEngine.load(masked_model, intra_op_threads=1, execution=Execution(cuda_graphs=True))
    assert sorted(replayed.bundle.replays) == ["masked.onnx", "residual.onnx"] and not plain.bundle.replays
    for _ in range(2):                                 # the second time through, every shape's buffers are reused
        np.testing.assert_array_equal(replayed.generate(REQUEST).joints, plain.generate(REQUEST).joints)
    assert all(0 < graph.captured_shapes <= 16 for graph in replayed.bundle.replays.values())
    # /health's model details name what is captured: nothing on the CPU provider
    assert replayed.limits.details["execution"] == {"providers": ["cpu"], "cuda_graphs": []}


def test_a_graph_onnxruntime_will_not_capture_is_served_without(masked_model, monkeypatch, caplog):
    """An older export (Range or an attention scale fed by Shape) makes onnxruntime refuse the session with
    enable_cuda_graph; the service warns and serves the graph plainly."""
    import t2m.runtime.bundle_loader as bundle_module

    def refuse(*args, **kwargs):
        raise RuntimeError("[ONNXRuntimeError] : 1 : FAIL : This session cannot use the graph capture feature")

    monkeypatch.setattr(bundle_module, "graph_session", refuse)
    with caplog.at_level(logging.WARNING):
        engine = OnnxEngine.load(masked_model, intra_op_threads=1, execution=Execution(cuda_graphs=True))
    assert "cannot be captured as a CUDA graph" in caplog.text and "masked.onnx" in caplog.text
    plain = OnnxEngine.load(masked_model, intra_op_threads=1)
    np.testing.assert_array_equal(engine.generate(REQUEST).joints, plain.generate(REQUEST).joints)
    assert all(graph.captured_shapes == 0 for graph in engine.bundle.replays.values())


def test_cuda_graphs_without_the_cuda_provider_are_refused_naming_both_settings():
    with pytest.raises(ValidationError, match="T2M_CUDA_GRAPHS=true needs T2M_EXECUTION_PROVIDERS=cuda"):
        Settings(cuda_graphs=True)
    execution = Settings(cuda_graphs=True, cuda_graph_shapes=4, execution_providers=["cuda"]).execution
    assert execution.cuda_graphs and execution.graph_shapes == 4


def test_families_with_a_growing_cache_replay_nothing(default_model, gpt_model):
    for model in (default_model, gpt_model):
        engine = OnnxEngine.load(model, intra_op_threads=1, execution=Execution(cuda_graphs=True))
        assert engine.bundle.replays == {} and "gpt_step_fixed.onnx" not in engine.bundle.sessions


@pytest.fixture(scope="module")
def fixed_step_bundle(tmp_path_factory):
    """A GPT-family bundle that carries gpt_step_fixed.onnx (`t2m import t2m-gpt --cuda-graph-step`)."""
    from t2m.families.gpt.random_bundle import build_random_bundle

    return build_random_bundle(tmp_path_factory.mktemp("fixed") / "gpt", block_size=40, fixed_step=True)


GPT_REQUESTS = [GenerationRequest([SegmentRequest("a person walks forward", 2.0)], seed=4, guidance=3.0),
                GenerationRequest([SegmentRequest("a person jumps", None), SegmentRequest("a person sits", 1.0)],
                                  seed=9, guidance=1.0, top_k=5)]


def test_the_gpt_familys_fixed_step_serves_with_cuda_graphs_only(fixed_step_bundle):
    """Listed and verified like any bundle file, opened only with T2M_CUDA_GRAPHS; then the cohorts step through
    FixedCacheGptStep and give the plain step's motions (the same codes on the CPU provider)."""
    from t2m.runtime.graphed_step import FixedCacheGptStep
    from t2m.runtime.onnx_step import OnnxGptStep

    plain = OnnxEngine.load(fixed_step_bundle, intra_op_threads=1)
    fixed = OnnxEngine.load(fixed_step_bundle, intra_op_threads=1, execution=Execution(cuda_graphs=True))
    assert "gpt_step_fixed.onnx" not in plain.bundle.sessions and type(plain.codes.step) is OnnxGptStep
    assert isinstance(fixed.codes.step, FixedCacheGptStep)
    # /health names it as captured where the providers are a GPU's (here: nothing is captured on the CPU)
    assert fixed.limits.details["execution"]["cuda_graphs"] == []
    on_gpu = dataclasses.replace(fixed.bundle, execution=Execution(("cuda",), cuda_graphs=True))
    assert on_gpu.cuda_graphs == ["gpt_step_fixed.onnx"]
    for request in GPT_REQUESTS * 2:          # the second time through, a finished cohort's buffers are reused
        want, got = plain.generate(request), fixed.generate(request)
        assert [(s.start_frame, s.end_frame) for s in got.segments] == \
            [(s.start_frame, s.end_frame) for s in want.segments]
        np.testing.assert_array_equal(got.joints, want.joints)


def test_a_fixed_step_onnxruntime_will_not_capture_leaves_the_plain_step(fixed_step_bundle, monkeypatch, caplog):
    import t2m.runtime.bundle_loader as bundle_module
    from t2m.runtime.onnx_step import OnnxGptStep

    def refuse(*args, **kwargs):
        raise RuntimeError("[ONNXRuntimeError] : 1 : FAIL : This session cannot use the graph capture feature")

    monkeypatch.setattr(bundle_module, "graph_session", refuse)
    with caplog.at_level(logging.WARNING):
        engine = OnnxEngine.load(fixed_step_bundle, intra_op_threads=1, execution=Execution(cuda_graphs=True))
    assert "gpt_step_fixed.onnx cannot be captured" in caplog.text
    assert type(engine.codes.step) is OnnxGptStep
