"""The GPT step over a fixed-capacity cache (model/networks/fixed_cache.py, export/graphs/gpt.py's
gpt_step_fixed.onnx, engine/graphed_step.py), run here on the CPU device: the same codes as the growing-cache step
with rows finishing at different steps, the buffers of a finished cohort reused, and a graph a CUDA graph can
capture (no control flow, no shape arithmetic)."""
from __future__ import annotations

import collections

import numpy as np
import onnx
import pytest
import torch

from t2m.decoding.lockstep import SamplingJob
from t2m.export.graphs.export import ort_session
from t2m.families.gpt.export_graphs import export_gpt_fixed_cache_step, export_gpt_step
from t2m.families.gpt.fixed_cache import empty_fixed_cache, fixed_cache_step
from t2m.families.gpt.loop import GptCohort
from t2m.families.gpt.network import GPTConfig, MotionGPT
from t2m.runtime.graphed_step import FixedCacheGptStep, GraphedSession, graph_session
from t2m.runtime.onnx_step import OnnxGptStep

MAX_TOKENS = 12


def _gpt(length_conditioning: bool) -> MotionGPT:
    torch.manual_seed(0)
    config = GPTConfig(codebook_size=32, embed=32, n_head=4, n_layer_base=1, n_layer_head=1,
                       block_size=MAX_TOKENS + 1, dropout=0.0, text_dim=16, length_conditioning=length_conditioning)
    return MotionGPT(config).eval()


@pytest.fixture(scope="module", params=[True, False], ids=["length", "no-length"])
def steps(request, tmp_path_factory):
    """(the growing-cache step, the fixed-cache step, the fixed graph's path) of one tiny random GPT."""
    gpt = _gpt(request.param)
    folder = tmp_path_factory.mktemp("fixed")
    plain_path = export_gpt_step(gpt, folder / "gpt_step.onnx")
    fixed_path = export_gpt_fixed_cache_step(gpt, folder / "gpt_step_fixed.onnx")
    c = gpt.config
    plain = OnnxGptStep(ort_session(plain_path), c.n_layer, c.n_head, c.head_dim, c.length_conditioning)
    session = graph_session(fixed_path, ["CPUExecutionProvider"], cuda_graph=True, options=None)
    fixed = FixedCacheGptStep(session, c.n_layer, c.n_head, c.head_dim, c.block_size, c.length_conditioning,
                              cuda_graph=True)         # graph ids in the run options: the CPU provider ignores them
    return plain, fixed, fixed_path


def _jobs(seed: int) -> list[SamplingJob]:
    """Segments of 2, 5 and 9 tokens and a free one (rows leave at different steps), one job without guidance."""
    cond = np.random.default_rng(seed).normal(size=(5, 16)).astype(np.float32)
    return [SamplingJob.of(cond[:3], [5, 2, None], max_tokens=MAX_TOKENS, guidance=3.0, temperature=0.9, top_k=8,
                           rng=seed),
            SamplingJob.of(cond[3:], [9, 3], max_tokens=MAX_TOKENS, guidance=1.0, rng=seed + 1)]


def _codes(step, seed: int) -> list[list[list[int]]]:
    end_id = 32
    return [[segment.tolist() for segment in job]  # type: ignore[union-attr]
            for job in GptCohort(step, _jobs(seed), MAX_TOKENS, end_id).run()]


def test_the_torch_step_matches_the_growing_cache_step_row_by_row():
    gpt = _gpt(True)
    cond, length = torch.randn(3, 16), torch.tensor([0, 4, 7])
    past, cache = gpt.empty_cache(3), empty_fixed_cache(gpt, 3)
    token = torch.zeros(3, dtype=torch.long)
    with torch.no_grad():
        for position in range(6):
            want, past = gpt.forward_step(cond, token, position, length, past)
            got, cache = fixed_cache_step(gpt, cond, token, torch.full((3,), position), length, cache)
            torch.testing.assert_close(got, want, rtol=0, atol=1e-5)
            torch.testing.assert_close(cache[:, :, :, :, : position + 1], past, rtol=0, atol=1e-5)
            assert not cache[:, :, :, :, position + 1:].any()      # positions ahead are not written
            token = want.argmax(-1)


def test_rows_at_different_positions_are_each_their_own_sequence():
    """Row 0 at position 2 and row 1 at position 0 in one call give what each gives alone."""
    gpt = _gpt(False)
    cond = torch.randn(2, 16)
    with torch.no_grad():
        past = gpt.empty_cache(1)
        for position, token in enumerate([0, 5]):
            _, past = gpt.forward_step(cond[:1], torch.tensor([token]), position, None, past)
        cache = empty_fixed_cache(gpt, 2)
        cache[:, :, :1, :, :2] = past
        got, _ = fixed_cache_step(gpt, cond, torch.tensor([7, 0]), torch.tensor([2, 0]), None, cache)
        first, _ = gpt.forward_step(cond[:1], torch.tensor([7]), 2, None, past)
        second, _ = gpt.forward_step(cond[1:], torch.tensor([0]), 0, None, gpt.empty_cache(1))
    torch.testing.assert_close(got, torch.cat([first, second]), rtol=0, atol=1e-5)


def test_the_fixed_graph_gives_the_growing_graphs_codes(steps):
    plain, fixed, _ = steps
    for seed in (0, 1, 2):
        assert _codes(fixed, seed) == _codes(plain, seed)


def test_a_finished_cohorts_buffers_serve_the_next_cohort_of_its_size(steps):
    plain, fixed, _ = steps
    jobs = _jobs(3)[1:]                                         # 2 segments, no guidance: 2 rows
    cohort = GptCohort(fixed, jobs, MAX_TOKENS, 32)
    used = cohort.batch.past
    cohort.run()
    assert fixed.empty_cache(2) is used                         # a finished cohort's buffers come back...
    assert fixed.empty_cache(2) is not used                     # ...once
    for seed in (4, 5):                                         # reused buffers: their stale positions are never read
        assert _codes(fixed, seed) == _codes(plain, seed)


def test_the_fixed_graph_has_what_a_cuda_graph_needs(steps):
    """onnxruntime refuses a CUDA graph over control flow (If, Loop, Scan), and shape arithmetic on the batch would
    run on the CPU provider; only the batch axis is dynamic."""
    _, _, path = steps
    model = onnx.load(str(path))
    ops = collections.Counter(node.op_type for node in model.graph.node)
    assert not {"If", "Loop", "Scan", "Shape", "ConstantOfShape"} & set(ops), ops
    dims = {value.name: [d.dim_param or d.dim_value for d in value.type.tensor_type.shape.dim]
            for value in [*model.graph.input, *model.graph.output]}
    assert dims["past_kv"] == dims["present_kv"] == [2, 2, "batch", 4, MAX_TOKENS + 1, 8]
    assert dims["position"] == ["batch"]


def test_a_graphed_session_gives_the_sessions_outputs_with_buffers_per_shape(tmp_path):
    """GraphedSession over the growing-cache graph: every call of a decode (a new past length each step, two batch
    sizes) gives session.run's outputs; a shape seen before reuses its buffers (one bound call per shape)."""
    gpt = _gpt(True)
    c = gpt.config
    path = export_gpt_step(gpt, tmp_path / "gpt_step.onnx")
    plain = ort_session(path)
    graphed = GraphedSession(graph_session(path, ["CPUExecutionProvider"], cuda_graph=True), cuda_graph=True)
    rng = np.random.default_rng(0)
    for _ in range(2):                          # the second decode replays the first one's shapes
        for batch in (1, 3):
            past = np.zeros((c.n_layer, 2, batch, c.n_head, 0, c.head_dim), np.float32)
            for position in range(4):
                feeds = {"cond": rng.normal(size=(batch, 16)).astype(np.float32),
                         "token": rng.integers(0, 32, batch), "position": np.asarray([position]),
                         "length": np.full(batch, 3), "past_kv": past}
                want = plain.run(None, feeds)
                got = graphed.run(None, feeds)
                for a, b in zip(want, got):
                    np.testing.assert_array_equal(b, a)
                assert graphed.run(["logits"], feeds)[0].shape == (batch, 33)
                past = got[1]
    assert graphed.captured_shapes == 2 * 4  # (batch, past length) pairs, bound once each
    kept = graphed.run(None, feeds)[0]
    graphed.run(None, {**feeds, "cond": feeds["cond"] + 1.0})   # the same shape: its buffers are overwritten...
    np.testing.assert_array_equal(kept, plain.run(None, feeds)[0])   # ...but not what an earlier call returned


def test_shapes_past_the_cap_run_plainly_with_the_same_outputs(tmp_path):
    """Each captured shape holds device memory for the session's life: past `max_shapes` a new shape is run as a
    plain call (graph id -1), the same numbers, nothing more kept."""
    gpt = _gpt(True)
    c = gpt.config
    path = export_gpt_step(gpt, tmp_path / "gpt_step.onnx")
    plain = ort_session(path)
    graphed = GraphedSession(graph_session(path, ["CPUExecutionProvider"], cuda_graph=True), cuda_graph=True,
                             max_shapes=2)
    rng = np.random.default_rng(1)
    for batch in (1, 2, 3, 4, 1):
        feeds = {"cond": rng.normal(size=(batch, 16)).astype(np.float32), "token": rng.integers(0, 32, batch),
                 "position": np.asarray([0]), "length": np.full(batch, 3),
                 "past_kv": np.zeros((c.n_layer, 2, batch, c.n_head, 0, c.head_dim), np.float32)}
        for a, b in zip(plain.run(None, feeds), graphed.run(None, feeds)):
            np.testing.assert_array_equal(b, a)
    assert graphed.captured_shapes == 2
    assert graphed.get_inputs() == graphed.session.get_inputs()     # the rest is the session's
