"""OnnxEngine end to end on the tiny random bundle: shapes, segment frames, seeds, batching, warnings."""
from __future__ import annotations

import numpy as np
import pytest

from t2m.runtime.types import GenerationRequest, RequestLimitError, SegmentRequest


def _request(seed=1, guidance=3.0, durations=(3.0, None, 0.5), **options) -> GenerationRequest:
    texts = ["a person walks forward", "a person waves with the right hand", "a person jumps"]
    return GenerationRequest(segments=[SegmentRequest(t, d) for t, d in zip(texts, durations)], seed=seed,
                             guidance=guidance, **options)


def test_motion_shape_and_segment_frames(onnx_engine):
    """0.5 s: round(0.5 * 20 / 4) = 2 steps (half to even), 8 decoded frames, fitted to the exact 10."""
    motion = onnx_engine.generate(_request(durations=(3.0, 2.0, 0.5)))
    assert motion.joints.shape == (60 + 40 + 10, 22, 3) and motion.joints.dtype == np.float32
    assert np.isfinite(motion.joints).all()
    assert [(s.start_frame, s.end_frame) for s in motion.segments] == [(0, 60), (60, 100), (100, 110)]
    assert motion.tokens == 27 and motion.fps == 20 and motion.seed == 1 and motion.warnings == []


def test_free_length_segment_is_whole_tokens(onnx_engine):
    motion = onnx_engine.generate(_request(durations=(None,)))
    frames = motion.segments[0].end_frame
    assert frames % 4 == 0 and 4 <= frames <= 4 * onnx_engine.limits.max_tokens
    assert len(motion.joints) == frames


def test_same_seed_same_motion_other_seed_differs(onnx_engine):
    first = onnx_engine.generate(_request(seed=5))
    again = onnx_engine.generate(_request(seed=5))
    other = onnx_engine.generate(_request(seed=6))
    assert np.array_equal(first.joints, again.joints)
    assert first.segments == again.segments
    assert first.joints.shape != other.joints.shape or not np.array_equal(first.joints, other.joints)


def test_batching_does_not_change_a_request(onnx_engine):
    alone = onnx_engine.generate(_request(seed=11, top_k=10, temperature=0.8))
    crowd = [_request(seed=s, guidance=g, durations=d) for s, g, d in
             [(1, 1.0, (10.0,)), (2, 0.0, (None, None)), (3, 5.0, (0.5, 4.0, None))]]
    results = onnx_engine.generate_batch(crowd[:2] + [_request(seed=11, top_k=10, temperature=0.8)] + crowd[2:])
    assert np.array_equal(results[2].joints, alone.joints)
    assert all(not isinstance(r, BaseException) for r in results)


def test_cancelled_request_is_not_generated(onnx_engine):
    request = _request()
    request.cancel()
    (result,) = onnx_engine.generate_batch([request])
    assert isinstance(result, Exception) and "cancelled" in str(result)


def test_guidance_without_unconditional_branch_is_flagged(bundle_without_uncond):
    from t2m.runtime.engine import OnnxEngine

    engine = OnnxEngine.load(bundle_without_uncond, intra_op_threads=1)
    assert engine.limits.unconditional_branch is False
    assert engine.generate(_request(guidance=1.0)).warnings == []
    warned = engine.generate(_request(guidance=2.0))
    assert len(warned.warnings) == 1 and "unconditional branch" in warned.warnings[0]


def test_engine_checks_limits_itself(onnx_engine):
    with pytest.raises(RequestLimitError, match="top_k"):
        onnx_engine.generate(_request(top_k=33))
    with pytest.raises(RequestLimitError, match=r"segments\.0\.duration"):
        onnx_engine.generate(_request(durations=(10.5,)))


def test_joint_names_and_parents_come_from_the_skeleton(onnx_engine):
    from t2m.motion.skeleton import SMPL22

    assert onnx_engine.limits.joint_names == SMPL22.joint_names
    assert onnx_engine.limits.parents == tuple(SMPL22.parents)
