"""The diffusion family served: tiny random MDM and DiP bundles over HTTP (3-sentence requests with
exact spans, seeds, streams, formats, 422s naming the field), the ONNX denoiser against the PyTorch module inside a
served sampling run with injected noise, determinism under batching, MDM's join windows and DiP's early frames."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from t2m.families.diffusion.random_bundle import build_random_diffusion_bundle, random_diffusion_model
from tests.service.served_stream import check_whole_and_streamed

torch.set_num_threads(1)

STREAM = [{"text": "a person walks forward", "duration": 1.0},
          {"text": "a person waves with the right hand", "duration": 1.5},
          {"text": "a person bows", "duration": 0.63}]          # 20, 30 and round(12.6) = 13 frames
SPANS = [(0, 20), (20, 50), (50, 63)]


@pytest.fixture(scope="module")
def bundles(tmp_path_factory):
    root = tmp_path_factory.mktemp("diffusion-serving")
    for arch in ("mdm", "dip"):
        build_random_diffusion_bundle(root / arch, arch=arch, seed=5)
    build_random_diffusion_bundle(root / "mdm-unmasked", arch="mdm", seed=5, mask_frames=False)
    return root


@pytest.fixture(scope="module")
def engines(bundles):
    from t2m.runtime.engine import OnnxEngine

    return {name: OnnxEngine.load(bundles / name, intra_op_threads=1) for name in ("mdm", "dip", "mdm-unmasked")}


def request(seed: int = 11, segments=STREAM, **options):
    from t2m.runtime.types import GenerationRequest, SegmentRequest

    return GenerationRequest(segments=[SegmentRequest(s["text"], s["duration"]) for s in segments], seed=seed,
                             guidance=options.pop("guidance", 2.5), **options)


@pytest.mark.parametrize("arch", ["mdm", "dip"])
def test_served_over_http_with_exact_spans_seeds_streams_and_formats(bundles, make_client, arch):
    from t2m.service.settings import Settings

    client = make_client(Settings(bundle_path=bundles / arch, intra_op_threads=1))
    health = client.get("/health").json()
    assert health["model"]["extra"]["family"] == "diffusion"
    assert health["model"]["extra"]["streaming"]["early_frames"] is (arch == "dip")
    body = {"segments": STREAM, "seed": 11}
    _, chunks = check_whole_and_streamed(client, body, SPANS)
    if arch == "dip":   # frames final call by call: several chunks; control: MDM sends its motion once it is made
        assert len(chunks) > 1
    for fmt in ("bvh", "glb"):
        assert client.post("/generate", json={**body, "format": fmt}).status_code == 200


@pytest.mark.parametrize(("body", "field"), [
    ({"segments": [{"text": "walk", "duration": 4.0}]}, "segments.0.duration"),     # MDM: 80 frames > 60
    ({"segments": [{"text": "walk", "duration": 1.0}, {"text": "run", "duration": None}]}, "segments.1.duration"),
    ({"segments": [{"text": "walk", "duration": 1.0}], "temperature": 0.5}, "temperature"),
    ({"segments": [{"text": "walk", "duration": 1.0}], "top_k": 1}, "top_k"),
])
def test_a_bad_request_is_a_422_naming_the_field(bundles, make_client, body, field):
    from t2m.service.settings import Settings

    client = make_client(Settings(bundle_path=bundles / "mdm", intra_op_threads=1))
    assert client.post("/generate", json={"segments": [{"text": "walk", "duration": 2.9}]}).status_code == 200
    refused = client.post("/generate", json=body)
    assert refused.status_code == 422
    detail = refused.json()["detail"]
    named = ([".".join(str(part) for part in error["loc"][1:]) for error in detail] if isinstance(detail, list)
             else [detail.split(":")[0]])
    assert field in named, detail


@pytest.mark.parametrize("arch", ["mdm", "dip"])
def test_the_onnx_denoiser_matches_the_module_inside_a_served_run(engines, arch):
    """The same served sampling run (texts from the bundle's text graph, joins, chains) over denoiser.onnx and over
    the PyTorch module the bundle was exported from, with the same injected noise."""
    from t2m.families.diffusion.loop import noise_from
    from t2m.families.diffusion.sampling import TorchDenoiser

    engine = engines[arch]
    codes = engine.codes

    def run(denoiser, model_seed: int = 5) -> np.ndarray:
        job = codes.job(request(), engine.text, engine.limits)
        rng = np.random.default_rng(99)
        job.noise = noise_from(lambda shape: rng.standard_normal(shape).astype(np.float32))
        original = codes.denoiser
        codes.denoiser = denoiser
        try:
            (segments,) = codes.sample([job], engine.limits.max_tokens, None)
        finally:
            codes.denoiser = original
        return np.concatenate(segments)

    graph = run(codes.denoiser)
    module = run(TorchDenoiser(random_diffusion_model(arch, 5)))
    other = run(TorchDenoiser(random_diffusion_model(arch, 6)))
    assert graph.shape == (63, 263)
    assert np.abs(graph - module).max() < 1e-4
    assert np.abs(graph - other).max() > 0.1            # control: another model's weights differ


@pytest.mark.parametrize("name", ["mdm", "dip", "mdm-unmasked"])
def test_a_request_is_the_same_alone_and_batched_with_others(engines, name):
    engine = engines[name]
    shorter = [{"text": "a person jumps", "duration": 0.8}, {"text": "a person sits", "duration": 1.2}]
    a, b = request(3), request(4, shorter, guidance=1.0)
    together = engine.generate_batch([a, b])
    alone = [engine.generate(a), engine.generate(b)]
    for batched, single in zip(together, alone):
        assert not isinstance(batched, BaseException)
        assert batched.joints.shape == single.joints.shape
        assert np.abs(batched.joints - single.joints).max() < 1e-4
    assert np.abs(engine.generate(request(5)).joints - alone[0].joints).max() > 1e-2   # control: another seed


def test_the_join_window_remakes_only_the_frames_around_each_join(engines):
    """MDM's joins: the same seed with and without the in-between pass: the sentences' frames are equal outside
    the windows' made part, and the known frames come out exactly."""
    from t2m.families.diffusion.loop import join_windows

    engine = engines["mdm"]
    codes = engine.codes

    def made(settings) -> np.ndarray:
        original = codes.settings
        codes.settings = settings
        try:
            (segments,) = codes.sample([codes.job(request(), engine.text, engine.limits)], 60, None)
        finally:
            codes.settings = original
        return np.concatenate(segments)

    joined, plain = made(codes.settings), made(dataclasses.replace(codes.settings, join_frames=0))
    windows = join_windows([20, 30, 13], codes.settings.join_frames, codes.settings.join_context)
    assert [(w.start, w.end) for w in windows] == [(12, 28), (42, 58)]
    changed = np.flatnonzero(np.abs(joined - plain).max(axis=1) > 0)
    remade = [frame for w in windows for frame in range(w.start + w.before, w.end - w.after)]
    assert changed.tolist() == remade                   # control: every remade frame moved, nothing else did
    for window in windows:                              # the known frames (context) are exactly the sentences'
        np.testing.assert_array_equal(joined[window.start:window.start + window.before],
                                      plain[window.start:window.start + window.before])


def test_dip_streams_each_call_as_it_is_made(engines):
    """The engine's streaming hook gets the frames kept after every call (16-frame calls: 20 + 30 + 13 frames are
    16 + 4, 16 + 14, 13 frames kept) and sends them at engine/streaming.py's cadence (the first call's at once,
    then whenever at least as many as were sent are final): 16, then 20; the rest comes with the whole motion.
    Control: MDM's hook is never called."""
    sent: list[np.ndarray] = []
    motion = engines["dip"].generate(request(on_frames=sent.append))
    assert [len(chunk) for chunk in sent] == [16, 20]
    np.testing.assert_allclose(np.concatenate(sent), motion.joints[:36], atol=1e-5)
    mdm: list[np.ndarray] = []
    engines["mdm"].generate(request(on_frames=mdm.append))
    assert mdm == []


def test_a_dip_crossfade_changes_only_the_later_sentences_and_stays_deterministic_under_batching(engines):
    """diffusion.crossfade: the same seed with and without it: the first sentence's frames are equal (its calls do
    not fade), the second's first call moves; a cross-faded request is the same alone and batched with another."""
    engine = engines["dip"]
    codes = engine.codes

    def made(settings, requests) -> list[np.ndarray]:
        original = codes.settings
        codes.settings = settings
        try:
            jobs = [codes.job(one, engine.text, engine.limits) for one in requests]
            return [np.concatenate(segments) for segments in codes.sample(jobs, 60, None)]
        finally:
            codes.settings = original

    faded = dataclasses.replace(codes.settings, crossfade=8)
    (plain,), (crossed,) = made(codes.settings, [request()]), made(faded, [request()])
    np.testing.assert_array_equal(crossed[:20], plain[:20])
    assert np.abs(crossed[20:36] - plain[20:36]).max() > 1e-3
    together = made(faded, [request(), request(4, guidance=1.0)])
    assert np.abs(together[0] - crossed).max() < 1e-5


@pytest.mark.parametrize("name", ["mdm", "dip", "mdm-unmasked"])
def test_with_cuda_graphs_the_denoiser_is_replayed_and_gives_the_plain_motion(bundles, engines, name):
    """T2M_CUDA_GRAPHS opens denoiser.onnx as a replayed graph (engine/graphed_step.py GraphedSession): here on the
    CPU provider, which captures nothing, the same motion for a seed, its calls through the replay buffers (one
    shape per distinct call; the 2022 MDM without frame masks crops per length). The exported denoisers have no
    host copy inside a run, so onnxruntime can capture them on a GPU (t2m/export/graphs/capture_check.py)."""
    from t2m.export.graphs.capture_check import capture_blockers
    from t2m.runtime.engine import OnnxEngine
    from t2m.runtime.execution import Execution

    replayed = OnnxEngine.load(bundles / name, intra_op_threads=1, execution=Execution(cuda_graphs=True))
    assert list(replayed.bundle.replays) == ["denoiser.onnx"]
    for _ in range(2):                                   # the second time through, every shape's buffers are reused
        np.testing.assert_array_equal(replayed.generate(request(7)).joints, engines[name].generate(request(7)).joints)
    assert replayed.bundle.replays["denoiser.onnx"].captured_shapes > 0
    assert capture_blockers(bundles / name / "denoiser.onnx") == []
