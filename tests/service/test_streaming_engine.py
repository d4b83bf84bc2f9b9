"""Frames streamed while the codes are sampled, at the engine: the decoder's reach (measured on the graph when the
bundle loads) against the bound its convolutions and upsamplings give, the bound itself (changing code t + ahead + 1
leaves the frames of code t alone, changing code t + ahead does not), early frames equal to the whole decode, the
same frames whatever shares the batch, a failing frame sink that cannot fail the generation, and the same early
frames from a T2M-HiFiGPT bundle (code rows); the masked family's come at the end."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from t2m.runtime.reach import DecoderReach
from t2m.runtime.types import GenerationRequest, SegmentRequest

# onnxruntime picks its convolution kernels by sequence length, so a window decodes the same frames as the whole
# motion up to ~1e-6 (measured: at most 2.9e-6 m on the default model's joints)
STREAM_TOLERANCE_M = 1e-5


def graph_reach(decoder_onnx: Path, tokens: int = 96) -> DecoderReach:
    """The reach of a decoder graph computed from its nodes: per time position the first and last code it depends
    on, through every Conv (kernel, dilation, pads, stride; a tap whose weights are all zero reads nothing), Slice
    along time and nearest Resize in graph order, as one chain (a residual branch is the longer path, so the chain
    bounds it)."""
    onnx = pytest.importorskip("onnx")
    from onnx import numpy_helper

    graph = onnx.load(str(decoder_onnx)).graph
    constants = {init.name: numpy_helper.to_array(init) for init in graph.initializer}
    for node in graph.node:
        if node.op_type == "Constant":
            constants[node.output[0]] = numpy_helper.to_array(node.attribute[0].t)
    first = last = np.arange(tokens)
    for node in graph.node:
        attributes = {a.name: onnx.helper.get_attribute_value(a) for a in node.attribute}
        if node.op_type == "Conv":
            (kernel,), (dilation,) = attributes["kernel_shape"], attributes["dilations"]
            (stride,) = attributes["strides"]
            before, after = attributes["pads"]
            length = (len(first) + before + after - dilation * (kernel - 1) - 1) // stride + 1
            weight = constants[node.input[1]]
            used = weight.reshape(-1, kernel).any(axis=0)   # Conv1d weights are [out, in, kernel]
            taps = np.arange(length)[:, None] * stride - before + np.arange(kernel)[None] * dilation
            inside = (taps >= 0) & (taps < len(first)) & used[None]
            clipped = np.clip(taps, 0, len(first) - 1)
            first = np.where(inside, first[clipped], tokens).min(axis=1)
            last = np.where(inside, last[clipped], -1).max(axis=1)
        elif node.op_type == "Slice":   # a causal residual block trims its conv (t2m/model/networks/vqvae.py)
            starts, ends, axes = (int(constants[name][0]) for name in node.input[1:4])
            assert axes in (2, -1), f"a Slice of axis {axes}: not along time"
            first, last = first[starts:ends], last[starts:ends]
        elif node.op_type == "Resize":
            assert attributes["mode"] == b"nearest" and attributes["nearest_mode"] == b"floor"
            factor = int(constants[node.input[2]][-1])
            first, last = np.repeat(first, factor), np.repeat(last, factor)
    per_token = len(first) // tokens
    code = np.arange(len(first)) // per_token
    middle = (code > tokens // 4) & (code < 3 * tokens // 4)   # clear of the zero padding at both ends
    return DecoderReach(ahead=int((last - code)[middle].max()), behind=int((code - first)[middle].max()))


@pytest.fixture(scope="module")
def gpt_engine(gpt_model):
    """The embedded GPT model: its decoder (reach 22 codes, 4 frames each) lets a 10 s motion stream early frames."""
    from t2m.runtime.engine import OnnxEngine

    return OnnxEngine.load(gpt_model, check_hashes=False, intra_op_threads=1)


def _request(segments, seed: int = 3, guidance: float = 3.0, sink=None) -> GenerationRequest:
    return GenerationRequest(segments=[SegmentRequest(text, duration) for text, duration in segments], seed=seed,
                             guidance=guidance, on_frames=sink)


def _streamed(engine, segments, seed: int = 3) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """(the early chunks, the streamed motion = early chunks + the rest of the Motion, the unstreamed joints)."""
    chunks: list[np.ndarray] = []
    motion = engine.generate(_request(segments, seed, sink=chunks.append))
    early = sum(len(chunk) for chunk in chunks)
    streamed = np.concatenate([*chunks, motion.joints[early:]])
    return chunks, streamed, engine.generate(_request(segments, seed)).joints


def test_the_gpt_decoder_reaches_22_codes_each_way_as_its_graph_says(gpt_engine, gpt_model):
    """T2M-GPT's decoder: conv3, then per upsampling level dilated residual blocks (9, 3, 1) and x2 nearest, then
    conv3 x2: a frame of code t depends on codes t - 22 .. t + 22."""
    assert gpt_engine.reach == graph_reach(gpt_model / "decoder.onnx") == DecoderReach(ahead=22, behind=22)
    assert gpt_engine.limits.details["streaming"] == {"early_frames": True, "lookahead_tokens": 22,
                                                      "lookbehind_tokens": 22, "every_tokens": 8}


def test_the_default_decoder_looks_3_steps_ahead_and_35_back_as_its_graph_says(default_model):
    """The default's decoder (0.3.0: causal residual blocks, three x2 levels, 8 frames per step) looks 3 steps ahead
    (its 0.2 decoder: 25, as many as a 10 s motion has): a one-sentence motion streams early frames. It looks 35 steps
    back, not the 48 its kernels span: the t - 18 taps of the dilation-9 blocks of the first two levels never lay
    inside a 64-frame training window (8 and 16 positions), so they kept their zero start (train_vq_decoder)."""
    from t2m.runtime.engine import OnnxEngine

    engine = OnnxEngine.load(default_model, check_hashes=False, intra_op_threads=1)
    assert engine.reach == graph_reach(default_model / "decoder.onnx") == DecoderReach(ahead=3, behind=35)
    assert engine.limits.max_tokens == 25 and engine.limits.details["streaming"]["lookahead_tokens"] == 3
    chunks, streamed, whole = _streamed(engine, [("a person walks forward", 10.0)])
    assert len(chunks[0]) == 8 and len(chunks) >= 3
    assert np.abs(streamed - whole).max() < STREAM_TOLERANCE_M


@pytest.mark.parametrize("segments, spans", [
    ([("a person walks forward", 9.9)], [(0, 198)]),
    ([("a person walks forward", 3.1), ("a person runs", None), ("a person bows", 1.9)], None),
], ids=["9.9s", "3.1-free-1.9"])
def test_the_default_model_streams_exact_durations_early_equal_to_the_whole(default_model, segments, spans):
    """8 frames a step: 9.9 s is 25 steps, 200 decoded frames fitted to 198 (engine/timeline.py). The first step's 8
    decoded frames are final once step 4 is sampled and complete the first 7 fitted frames (frame 6 samples decoded
    time 6 * 199 / 197 < 7), which go out at once; the stream put together is the whole answer, spans exact."""
    from t2m.runtime.engine import OnnxEngine

    engine = OnnxEngine.load(default_model, check_hashes=False, intra_op_threads=1)
    chunks, streamed, whole = _streamed(engine, segments)
    motion = engine.generate(_request(segments))
    assert streamed.shape == whole.shape and np.abs(streamed - whole).max() < STREAM_TOLERANCE_M
    assert chunks and len(chunks[0]) == 7
    found = [(s.start_frame, s.end_frame) for s in motion.segments]
    if spans is not None:
        assert found == spans and len(chunks) >= 3
    else:   # the free segment keeps its whole steps, the others are exact
        assert found[0] == (0, 62) and (found[1][1] - found[1][0]) % 8 == 0 and found[2][1] - found[2][0] == 38
    assert found[-1][1] == len(whole)


def test_the_random_bundle_reach_is_its_graph_bound(onnx_engine, random_bundle):
    assert onnx_engine.reach == graph_reach(random_bundle / "decoder.onnx")
    assert onnx_engine.reach.ahead < 10   # one residual block per level: a short reach, many early frames


def test_frames_of_code_t_are_final_once_codes_up_to_t_plus_ahead_exist(gpt_engine):
    decode, ahead, per = gpt_engine.decoder.decode, gpt_engine.reach.ahead, 4
    rng = np.random.default_rng(11)
    codes = rng.integers(0, 512, 70)
    whole = decode(codes)
    t = 30
    frames_of_t = slice(0, (t + 1) * per)
    moved_at_reach = False
    for replacement in rng.integers(0, 512, 4):
        beyond, at = codes.copy(), codes.copy()
        beyond[t + ahead + 1] = (codes[t + ahead + 1] + 1 + replacement) % 512
        at[t + ahead] = (codes[t + ahead] + 1 + replacement) % 512
        np.testing.assert_array_equal(decode(beyond)[frames_of_t], whole[frames_of_t])
        moved_at_reach |= not np.array_equal(decode(at)[t * per:(t + 1) * per], whole[t * per:(t + 1) * per])
    assert moved_at_reach, "the bound is not tight: code t + ahead never changes the frames of code t"
    # so the codes up to t + ahead alone decode the frames up to code t
    prefix = decode(codes[:t + ahead + 1])
    assert np.abs(prefix[frames_of_t] - whole[frames_of_t]).max() < 1e-5


@pytest.mark.parametrize("segments", [
    [("a person walks forward", 10.0)],
    [("a person walks forward", None), ("a person waves with the right hand", None)],
    [("a person runs", 7.0), ("a person bows", 9.0), ("a person jumps", 2.0)],
], ids=["one-10s", "two-free", "three"])
def test_early_frames_and_the_rest_equal_the_unstreamed_motion(gpt_engine, segments):
    chunks, streamed, whole = _streamed(gpt_engine, segments)
    assert streamed.shape == whole.shape
    assert np.abs(streamed - whole).max() < STREAM_TOLERANCE_M
    assert chunks, "nothing was sent before the whole decode"
    assert len(chunks[0]) == 4   # the first final code goes out at once
    assert all(len(chunk) % 4 == 0 for chunk in chunks)


def test_a_10s_motion_sends_its_early_frames_in_doubling_chunks(gpt_engine):
    """50 codes, reach 22: codes 0..27 can be final before the end. Sent: the first final code at once, then when at
    least 8 codes and at least as many as sent before are newly final: at 1, 9 and 18 final codes (27 - 18 < 18)."""
    chunks, _, _ = _streamed(gpt_engine, [("a person walks forward", 10.0)], seed=5)
    assert [len(chunk) for chunk in chunks] == [4, 32, 36]


def test_the_random_bundle_streams_equal_frames_too(onnx_engine):
    chunks, streamed, whole = _streamed(onnx_engine, [("a person walks", 10.0), ("a person waves", None)], seed=8)
    assert len(chunks) > 2
    assert np.abs(streamed - whole).max() < STREAM_TOLERANCE_M


def test_a_streamed_request_gets_the_same_frames_alone_or_batched(gpt_engine):
    segments = [("a person walks forward", 10.0)]
    alone: list[np.ndarray] = []
    batched: list[np.ndarray] = []
    first = gpt_engine.generate_batch([_request(segments, 4, sink=alone.append)])[0]
    results = gpt_engine.generate_batch([_request([("a person bows", 3.0)], 9),
                                             _request(segments, 4, sink=batched.append),
                                             _request([("a person runs", 8.0), ("a person sits", None)], 2)])
    assert len(alone) == len(batched) > 1
    for a, b in zip(alone, batched):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(results[1].joints, first.joints)


def test_a_failing_frame_sink_does_not_fail_the_generation(gpt_engine):
    calls = []

    def broken(frames: np.ndarray) -> None:
        calls.append(len(frames))
        raise RuntimeError("the client went away")

    motion = gpt_engine.generate(_request([("a person walks forward", 10.0)], 6, sink=broken))
    assert calls == [4]   # one try, then the early frames stop
    np.testing.assert_array_equal(motion.joints, gpt_engine.generate(_request([("a person walks forward", 10.0)],
                                                                                  6)).joints)


def test_the_masked_family_sends_its_frames_only_with_the_whole_motion(masked_bundle):
    from t2m.runtime.engine import OnnxEngine

    engine = OnnxEngine.load(masked_bundle, intra_op_threads=1)
    assert engine.reach is None
    assert engine.limits.details["streaming"]["early_frames"] is False
    chunks: list[np.ndarray] = []
    motion = engine.generate(_request([("a person walks forward", 2.0)], guidance=4.0, sink=chunks.append))
    assert chunks == [] and len(motion.joints) == 40


def test_a_hifigpt_bundle_streams_early_frames_equal_to_the_unstreamed_motion(hifigpt_bundle):
    """T2M-HiFiGPT's decoder reads a row of R codes per step: the probe changes a whole row, and finds its graph's
    bound; its loop reports each position's rows, so frames go early as for the GPT family."""
    from t2m.runtime.engine import OnnxEngine

    engine = OnnxEngine.load(hifigpt_bundle, intra_op_threads=1)
    assert engine.reach == graph_reach(hifigpt_bundle / "decoder.onnx")
    assert engine.limits.details["streaming"]["early_frames"] is True
    chunks, streamed, whole = _streamed(engine, [("a person walks", 8.0), ("a person waves", None)], seed=8)
    assert len(chunks) >= 2 and len(chunks[0]) == 8   # the first final step's 8 frames at once
    assert streamed.shape == whole.shape
    assert np.abs(streamed - whole).max() < STREAM_TOLERANCE_M


def test_a_causal_decoder_looks_three_steps_ahead_and_streams_a_one_sentence_motion_early(tmp_path, hifigpt_bundle):
    """A decoder whose residual blocks read only past frames (VQConfig.causal_decoder_blocks): its graph's bound
    (through the trimming Slice) is what the probe measures, it looks 3 steps ahead (at most: conv_in's next code,
    and the k=3 convolutions after each x2 level), fewer than the same decoder without causal blocks, and a motion of
    one sentence gets early frames equal to its whole decode."""
    from t2m.families.hifigpt.random_bundle import build_random_hifigpt_bundle
    from t2m.runtime.engine import OnnxEngine

    bundle = build_random_hifigpt_bundle(tmp_path / "causal", depth=3, codebook_size=16, seed=2,
                                         causal_decoder_blocks=True)
    engine = OnnxEngine.load(bundle, intra_op_threads=1)
    symmetric = OnnxEngine.load(hifigpt_bundle, intra_op_threads=1)
    assert engine.reach == graph_reach(bundle / "decoder.onnx")
    assert engine.reach.ahead <= 3 and engine.reach.ahead < symmetric.reach.ahead
    assert engine.reach.behind > symmetric.reach.behind   # the causal blocks look twice as far back
    chunks, streamed, whole = _streamed(engine, [("a person walks", 10.0)], seed=8)
    assert len(chunks[0]) == 8 and sum(len(chunk) for chunk in chunks) >= len(whole) // 2   # chunks double
    assert np.abs(streamed - whole).max() < STREAM_TOLERANCE_M
