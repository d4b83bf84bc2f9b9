"""Speed of diffusion-family bundles (MDM, DiP) beside the authors' published GPU figures, on several thread counts,
float32 and with denoiser.onnx quantised to int8 (t2m/bench/released_models.py prints it for the releases).

Per bundle and thread count: ms per denoiser call (one batch of the guidance pair: conditional + null row; MDM at
its longest, 196 frames; DiP at its 20 + 40 frames), then whole requests through the engine's own stages
(t2m.bench.bundles.bench_engine): a DiP call (2 s of motion, 10 steps) and a DiP 10 s sentence (5 calls), an
MDM motion of 9.8 s (196 frames, its longest; a 1000-step model is estimated as 1000 calls, not run). int8:
onnxruntime's dynamic quantisation of denoiser.onnx (t2m.export.writing.quantize.quantize_graph) swapped into the
engine, its parity against float32: max |x0 diff| on the call above and max |diff| of a whole seeded run (the same
injected noise; normalised features).
"""
from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from t2m.bench.bundles import bench_engine
from t2m.bench.machine import describe_machine
from t2m.runtime.engine import OnnxEngine

__all__ = ["ANCHORS", "codes_of", "denoiser_feed", "run_diffusion_speed"]

# published by the authors (README; assets/dip_spec.png, one RTX 3090), not measured here
ANCHORS = {
    "mdm-1000": "MDM paper model (1000 steps): ~40x slower than the 0.4 s of MDM-50 (README: 50 steps 'runs 20X "
                "faster' and cached CLIP '2X faster')",
    "mdm-50": "400 ms per sample (MDM, 50 steps; 500 frames/s)",
    "dip": "11 ms per call of 40 frames (3,500 frames/s)",
}
DIP_CALL = (("a person walks forward", 2.0),)
DIP_SENTENCE = (("a person walks forward", 10.0),)
MDM_MOTION = (("a person walks forward", 9.8),)


def codes_of(engine: OnnxEngine) -> Any:
    """The engine's served object (t2m.families.diffusion.served.DiffusionCodes for these bundles)."""
    return engine.codes


def denoiser_feed(engine: OnnxEngine, seed: int = 0) -> dict[str, np.ndarray]:
    """One denoiser call as a request at default guidance makes it: 2 rows (a text and the null text), MDM at 196
    frames, DiP at pred_len frames after its prefix; the text from the bundle's own text graph."""
    s, features = codes_of(engine).settings, codes_of(engine).features
    frames = s.pred_len or min(engine.limits.max_tokens, 196)
    rng = np.random.default_rng(seed)
    names = {graph_input.name for graph_input in codes_of(engine).denoiser.session.get_inputs()}
    feed = {"x_t": rng.standard_normal((2, frames, features)).astype(np.float32),
            "t": np.array([s.steps - 1, s.steps - 1], np.int64), "length": np.array([frames, frames], np.int64)}
    if s.tokens:
        from t2m.runtime.text import encode_token_states

        (states,), _ = encode_token_states(engine.text, ["a person walks forward"])
        feed["text"] = np.stack([states, np.zeros_like(states)])
        feed["text_mask"] = np.ones((2, len(states)), bool)
    else:
        text = engine.text.encode(["a person walks forward"])[0]
        feed["text"] = np.stack([text, np.zeros_like(text)])
    if s.chained:
        assert codes_of(engine).prefix is not None
        feed["prefix"] = np.stack([codes_of(engine).prefix] * 2)
    return {name: np.asarray(value) for name, value in feed.items() if name in names}


def call_ms(session: Any, feed: Mapping[str, np.ndarray], repeats: int) -> tuple[float, np.ndarray]:
    """(median ms of one run after a warm-up, its x0)."""
    (x0,) = session.run(["x0"], dict(feed))
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        session.run(["x0"], dict(feed))
        times.append((time.perf_counter() - start) * 1e3)
    return statistics.median(times), np.asarray(x0)


def seeded_run(engine: OnnxEngine, segments: Sequence[tuple[str, float]], seed: int = 7) -> np.ndarray:
    """One request's normalised frames with injected noise (the same draws for every denoiser)."""
    from t2m.families.diffusion.loop import noise_from
    from t2m.runtime.types import GenerationRequest, SegmentRequest

    request = GenerationRequest(segments=[SegmentRequest(text, duration) for text, duration in segments], seed=seed,
                                guidance=engine.limits.guidance())
    job = codes_of(engine).job(request, engine.text, engine.limits)
    rng = np.random.default_rng(seed)
    job.noise = noise_from(lambda shape: rng.standard_normal(shape).astype(np.float32))
    (parts,) = codes_of(engine).sample([job], engine.limits.max_tokens, None)
    assert parts is not None
    return np.concatenate(parts)


def _requests(name: str, engine: OnnxEngine, call: float, repeats: int) -> list[tuple[str, float]]:
    """(what, ms) of the whole requests timed for this model."""
    if name == "dip":
        return [("DiP call (2 s, 10 steps)", bench_engine(engine, DIP_CALL, repeats).total),
                ("DiP 10 s sentence (5 calls)", bench_engine(engine, DIP_SENTENCE, repeats).total)]
    if codes_of(engine).settings.steps > 100:          # 1000 steps: estimated, not run
        return [("9.8 s motion (est. steps x call)", codes_of(engine).settings.steps * call)]
    return [("9.8 s motion (196 frames)", bench_engine(engine, MDM_MOTION, repeats).total)]


def _int8_session(bundle: Path, folder: Path, threads: int) -> Any:
    from t2m.export.writing.quantize import quantize_graph
    from t2m.runtime.bundle_loader import open_session, session_options

    path = folder / "denoiser.onnx"
    if not path.is_file():
        folder.mkdir(parents=True, exist_ok=True)
        quantize_graph(bundle / "denoiser.onnx", path)
    return open_session(path, session_options(threads))


def run_diffusion_speed(bundles: Mapping[str, Path], int8_dir: Path, threads: Sequence[int], repeats: int = 3,
                        echo: Callable[[str], None] = print) -> list[dict[str, Any]]:
    """Print the diffusion table (float32 and int8 rows) and the int8 parity lines; returns the rows."""
    from t2m.families.diffusion.served import OnnxDenoiser

    echo(f"## Diffusion family at released sizes (random weights; median of {repeats}, batch 1, default guidance)")
    echo("")
    for line in describe_machine(max(threads)):
        echo(line)
    echo("")
    echo("| model | weights | threads | ms / denoiser call | request | ms | published (GPU, not measured here) |")
    echo("| --- | --- | ---: | ---: | --- | ---: | --- |")
    rows: list[dict[str, Any]] = []
    parity: list[str] = []
    for name, bundle in bundles.items():
        for count in threads:
            engine = OnnxEngine.load(bundle, intra_op_threads=count)
            feed = denoiser_feed(engine)
            float_denoiser = codes_of(engine).denoiser
            int8 = OnnxDenoiser(_int8_session(bundle, int8_dir / name, count))
            for label, denoiser in (("float32", float_denoiser), ("int8", int8)):
                codes_of(engine).denoiser = denoiser
                call, x0 = call_ms(denoiser.session, feed, max(repeats, 5))
                for what, ms in _requests(name, engine, call, repeats):
                    rows.append({"model": name, "weights": label, "threads": count, "call_ms": call,
                                 "request": what, "ms": ms})
                    echo(f"| {name} | {label} | {count} | {call:.1f} | {what} | {ms:.0f} | {ANCHORS[name]} |")
                if label == "float32":
                    reference_x0 = x0
                elif count == threads[0] and codes_of(engine).settings.steps <= 100:
                    segments = DIP_CALL if name == "dip" else MDM_MOTION
                    ran = seeded_run(engine, segments)
                    codes_of(engine).denoiser = float_denoiser
                    exact = seeded_run(engine, segments)
                    parity.append(f"- {name}: int8 vs float32: max |x0 diff| {np.abs(x0 - reference_x0).max():.3f} "
                                  f"on one call (x0 up to {np.abs(reference_x0).max():.2f}); whole seeded run "
                                  f"({len(exact)} frames, injected noise) max |diff| {np.abs(ran - exact).max():.3f}, "
                                  f"mean {np.abs(ran - exact).mean():.4f} (values up to {np.abs(exact).max():.2f})")
            codes_of(engine).denoiser = float_denoiser
    echo("")
    echo("- ms: whole request through the engine (text + denoising steps + de-normalisation + joints), wall time on "
         "this shared machine; a DiP call is 10 denoiser calls of the guidance pair; MDM's 9.8 s motion is its "
         "longest single sentence (196 frames); the 1000-step model's motion is estimated as 1000 calls")
    echo("- int8: onnxruntime dynamic quantisation of denoiser.onnx (weights int8, activations quantised per "
         "call), the text graph float32; random weights, so the parity says how far int8 moves this computation, "
         "not what it does to a trained model's quality")
    for line in parity:
        echo(line)
    return rows
