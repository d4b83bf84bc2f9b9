"""Step graphs with device-resident caches (onnxruntime I/O binding, engine/bound_step.py), run here on the CPU
device: the same logits, caches and codes as the numpy steps for the GPT and T2M-HiFiGPT random bundles, with rows
finishing at different steps, and the same motions under continuous batching."""
from __future__ import annotations

import importlib.util

import numpy as np
import onnxruntime as ort
import pytest

from t2m.decoding.lockstep import SamplingJob, keep_rows
from t2m.families.gpt.loop import GptCohort
from t2m.families.hifigpt.loop import HiFiGPTCohort
from t2m.runtime.bound_step import KEEP_ROWS_GRAPH, BoundGptStep, BoundTemporalStep, host_cache
from t2m.runtime.execution import Execution
from t2m.runtime.onnx_step import OnnxGptStep, OnnxTemporalStep
from t2m.runtime.types import GenerationRequest, Motion, SegmentRequest
from tests.service.conftest import REPO

BOUND = Execution(("cpu",), io_binding="on")


@pytest.fixture(scope="module")
def engines(random_bundle, hifigpt_bundle):
    """family -> (the numpy engine, the bound engine) on the same bundle."""
    from t2m.runtime.engine import OnnxEngine

    def pair(path):
        return (OnnxEngine.load(path, intra_op_threads=1),
                OnnxEngine.load(path, intra_op_threads=1, execution=BOUND))

    return {"gpt": pair(random_bundle), "hifigpt": pair(hifigpt_bundle)}


class Recording:
    """A step wrapper that keeps every call's host outputs and the cache it returned, as numpy."""

    def __init__(self, step) -> None:
        self.step, self.outputs, self.caches = step, [], []
        self.depth = getattr(step, "depth", None)

    def empty_cache(self, batch):
        return self.step.empty_cache(batch)

    def keep_rows(self, past, keep):
        return keep_rows(self.step, past, keep)

    def __call__(self, *args):
        *host, present = self.step(*args)
        self.outputs.append([np.array(value) for value in host])
        self.caches.append(host_cache(present))
        return (*host, present)


def _jobs(dim: int, seed: int = 0) -> list[SamplingJob]:
    """Segments that finish at different steps: fixed lengths 2, 5 and 9, a free one, one job without guidance."""
    rng = np.random.default_rng(seed)
    cond = rng.normal(size=(5, dim)).astype(np.float32)
    return [SamplingJob.of(cond[:3], [5, 2, None], max_tokens=12, guidance=3.0, temperature=0.9, top_k=8, rng=1),
            SamplingJob.of(cond[3:], [9, 3], max_tokens=12, guidance=1.0, rng=2)]


def _same_calls(numpy_step: Recording, bound_step: Recording) -> None:
    assert len(numpy_step.outputs) == len(bound_step.outputs) > 3
    for want, got in zip(numpy_step.outputs, bound_step.outputs):
        for a, b in zip(want, got):
            np.testing.assert_allclose(b, a, rtol=0, atol=1e-6)
    for want, got in zip(numpy_step.caches, bound_step.caches):
        assert want.shape == got.shape
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-6)


def _codes(results) -> list[list[list]]:
    return [[np.asarray(segment).tolist() for segment in job] for job in results]


def test_bound_gpt_step_gives_the_numpy_steps_logits_caches_and_codes(engines):
    plain, bound = (engine.codes.step for engine in engines["gpt"])
    assert type(plain) is OnnxGptStep and isinstance(bound, BoundGptStep)
    dim = engines["gpt"][0].bundle.manifest.text_dim
    numpy_step, bound_step = Recording(plain), Recording(bound)
    max_tokens, end = 12, engines["gpt"][0].bundle.manifest.settings.end_id
    want = GptCohort(numpy_step, _jobs(dim), max_tokens, end).run()
    got = GptCohort(bound_step, _jobs(dim), max_tokens, end).run()
    assert _codes(got) == _codes(want)
    _same_calls(numpy_step, bound_step)
    # control: rows left the batch on the way (the caches shrank), so keep_rows ran on bound caches
    assert len({cache.shape[2] for cache in bound_step.caches}) >= 3


def test_bound_hifigpt_steps_give_the_numpy_steps_outputs_and_codes(engines):
    plain, bound = (engine.codes for engine in engines["hifigpt"])
    assert type(plain.temporal) is OnnxTemporalStep and isinstance(bound.temporal, BoundTemporalStep)
    dim = engines["hifigpt"][0].bundle.manifest.text_dim
    want_steps = Recording(plain.temporal), Recording(plain.residual)
    got_steps = Recording(bound.temporal), Recording(bound.residual)
    want = HiFiGPTCohort(*want_steps, _jobs(dim, seed=1), 12).run()
    got = HiFiGPTCohort(*got_steps, _jobs(dim, seed=1), 12).run()
    assert _codes(got) == _codes(want)
    for numpy_step, bound_step in zip(want_steps, got_steps):
        _same_calls(numpy_step, bound_step)
    assert len({cache.shape[2] for cache in got_steps[0].caches}) >= 3


def test_a_bound_cache_stays_an_ortvalue_between_steps(engines):
    """Control that the binding is really used: the cache handed back is an OrtValue, not a host array."""
    bound = engines["gpt"][1].codes.step
    cond = np.zeros((2, engines["gpt"][1].bundle.manifest.text_dim), np.float32)
    _, present = bound(cond, np.zeros(2, np.int64), 0, np.zeros(2, np.int64), bound.empty_cache(2))
    assert isinstance(present, ort.OrtValue) and present.device_name() == "cpu"
    kept = bound.keep_rows(present, np.array([False, True]))
    assert isinstance(kept, ort.OrtValue) and kept.shape()[2] == 1
    np.testing.assert_array_equal(kept.numpy(), present.numpy()[:, :, [1]])
    assert bound.keep_rows(present, np.array([False, False])).shape[2] == 0


def _long(seed: int = 3) -> GenerationRequest:
    return GenerationRequest(segments=[SegmentRequest("a person walks forward", 10.0)], seed=seed, guidance=3.0)


def _stream(seed: int = 11) -> GenerationRequest:
    return GenerationRequest(segments=[SegmentRequest("a person waves with the right hand", 2.0),
                                       SegmentRequest("a person bows", None),
                                       SegmentRequest("a person jumps", 0.5)],
                             seed=seed, guidance=2.0, temperature=0.8, top_k=10)


def _same_motion(got: Motion | BaseException, want: Motion) -> bool:
    return (isinstance(got, Motion) and got.segments == want.segments and got.tokens == want.tokens
            and np.allclose(got.joints, want.joints, rtol=0, atol=1e-5))


@pytest.mark.parametrize("family", ["gpt", "hifigpt"])
def test_continuous_batching_with_bound_caches_gives_the_numpy_engines_motions(engines, family):
    plain, bound = engines[family]
    alone = {"long": plain.generate(_long()), "stream": plain.generate(_stream())}
    session = bound.continuous()
    long, stream = _long(), _stream()
    session.admit([long])
    for _ in range(4):
        assert session.advance() == []
    session.admit([stream])
    assert [r.cohort.position for r in session.running] == [4, 0]      # control: it joined mid-run
    finished = []
    while not session.idle:
        finished += session.advance()
    results = {id(request): result for request, result in finished}
    assert _same_motion(results[id(long)], alone["long"])
    assert _same_motion(results[id(stream)], alone["stream"])


@pytest.mark.parametrize("family", ["gpt", "hifigpt"])
def test_bound_engine_is_deterministic_and_batch_invariant(engines, family):
    _, bound = engines[family]
    first = bound.generate(_stream())
    batch = bound.generate_batch([_long(seed=5), _stream(), _long(seed=6)])
    assert _same_motion(batch[1], first) and _same_motion(bound.generate(_stream()), first)


def test_keep_rows_graph_is_current():
    """The committed one-node gather graph is what scripts/keep_rows_graph.py writes."""
    pytest.importorskip("onnx")
    spec = importlib.util.spec_from_file_location("keep_rows_graph", REPO / "scripts" / "keep_rows_graph.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert KEEP_ROWS_GRAPH.read_bytes() == module.build()


def test_keep_rows_default_slices_numpy_caches_and_prefers_the_steps_own():
    past = np.arange(2 * 2 * 3 * 1 * 1 * 1, dtype=np.float32).reshape(2, 2, 3, 1, 1, 1)
    keep = np.array([True, False, True])
    np.testing.assert_array_equal(keep_rows(object(), past, keep), past[:, :, [0, 2]])

    class Own:
        def keep_rows(self, past, keep):
            return "kept by the step"

    assert keep_rows(Own(), past, keep) == "kept by the step"
