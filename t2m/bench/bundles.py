"""Speed of whole requests on real bundles, every family side by side in one run (`t2m bench --bundle A --bundle B`).

`t2m bench` without bundles compares implementations of one GPT (onnxruntime + KV cache vs PyTorch eager); this
compares models: what the service's engine (the same objects `t2m serve` runs, no HTTP) spends on a 10 s motion from
one sentence and on a 3-sentence stream of 10 s, per stage: text encoding (+ the unknown-text check), codes (the
family's loop: GPT steps, HiFiGPT's temporal + depth steps, or masked re-masking + residual passes, at the model's
default guidance), decoding to features and joints. Torch-free, like the service. A model whose segments are shorter
(MoMask's and MoGenTS's releases: 49 token rows = 9.8 s) gets each segment cut to its longest, and the table says how
long the motion was.
"""
from __future__ import annotations

import os
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from t2m.bench.machine import describe_machine
from t2m.runtime.engine import OnnxEngine
from t2m.runtime.types import GenerationRequest, ModelLimits, SegmentRequest, tokens_for_duration

ONE_SENTENCE = (("a person walks forward", 10.0),)
STREAM = (("a person walks forward", 3.0), ("a person waves with the right hand", 3.0), ("a person bows", 4.0))
CASES: dict[str, tuple[tuple[str, float], ...]] = {"10 s, 1 sentence": ONE_SENTENCE,
                                                   "10 s, 3-sentence stream": STREAM}


@dataclass(frozen=True)
class StageTimes:
    """Median milliseconds per stage over the repeats (each repeat a fresh seed), for `seconds` of motion, and the
    median CPU milliseconds of the whole request (this process, all threads): on a machine shared with other work
    the wall time includes waiting for a core, the CPU time does not."""

    text: float
    codes: float
    decode: float
    seconds: float
    cpu: float

    @property
    def total(self) -> float:
        return self.text + self.codes + self.decode


def time_request(engine: OnnxEngine, request: GenerationRequest) -> tuple[float, float, float, float]:
    """One request through the engine's own stages (what OnnxEngine.generate_batch does for a batch of one): wall ms
    of text, codes and decode, and CPU ms of the whole request."""
    cpu_start = time.process_time()
    start = time.perf_counter()
    job = engine.codes.job(request, engine.text, engine.limits)
    warnings = engine.unknown_text_warnings([s.text for s in request.segments], job.conds)
    after_text = time.perf_counter()
    jobs: list = [job]  # the family's own job type (SamplingJob or MaskedJob)
    (codes,) = engine.codes.sample(jobs, engine.limits.max_tokens, None)
    after_codes = time.perf_counter()
    if codes is None:
        raise RuntimeError("the benchmark request was cancelled")
    engine._motion(request, codes, warnings)
    end = time.perf_counter()
    cpu = (time.process_time() - cpu_start) * 1e3
    return (after_text - start) * 1e3, (after_codes - after_text) * 1e3, (end - after_codes) * 1e3, cpu


def fit_segments(segments: Sequence[tuple[str, float]], limits: ModelLimits) -> list[tuple[str, float]]:
    """Each segment at most the model's longest (max_tokens codes), so a case runs on every model."""
    longest = limits.max_tokens * limits.frames_per_token / limits.fps
    return [(text, min(duration, longest)) for text, duration in segments]


def motion_seconds(segments: Sequence[tuple[str, float]], limits: ModelLimits) -> float:
    """Seconds of motion the segments give (whole codes of frames_per_token frames each)."""
    frames = sum(tokens_for_duration(d, limits.fps, limits.frames_per_token) * limits.frames_per_token
                 for _, d in segments)
    return frames / limits.fps


def bench_engine(engine: OnnxEngine, segments: Sequence[tuple[str, float]], repeats: int) -> StageTimes:
    guidance = engine.limits.guidance()
    segments = fit_segments(segments, engine.limits)
    samples = []
    for seed in range(repeats + 1):  # the first run warms the sessions up and is not counted
        request = GenerationRequest(segments=[SegmentRequest(text, duration) for text, duration in segments],
                                    seed=seed, guidance=guidance)
        samples.append(time_request(engine, request))
    text, codes, decode, cpu = (statistics.median(stage) for stage in zip(*samples[1:]))
    return StageTimes(text, codes, decode, motion_seconds(segments, engine.limits), cpu)


def describe(engine: OnnxEngine) -> str:
    """How the model decodes, in its family's words."""
    return engine.family.describe(engine.bundle.manifest, engine.limits.guidance())


def run_bundle_bench(bundles: Sequence[Path], repeats: int = 5, threads: int | None = None,
                     echo: Callable[[str], None] = print,
                     names: Sequence[str] | None = None) -> dict[str, dict[str, StageTimes]]:
    """Load every bundle, time both cases on each, print one markdown table; returns {model: {case: times}}.
    `names` labels the rows (default: each manifest's name; e.g. a float32 bundle and its quantised copies)."""
    threads = threads or os.cpu_count() or 1
    engines = [OnnxEngine.load(path, intra_op_threads=threads) for path in bundles]
    labels = list(names) if names is not None else [engine.limits.name for engine in engines]
    echo(f"## t2m bench --bundle ({len(engines)} models, median of {repeats} requests each, batch 1)")
    echo("")
    for line in describe_machine(threads):
        echo(line)
    echo("")
    echo("| model | family / decoding | request | s motion | ms text | ms codes | ms decode + joints | ms total "
         "| ms CPU |")
    echo("| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    results: dict[str, dict[str, StageTimes]] = {}
    for engine, name in zip(engines, labels):
        results[name] = {}
        for label, segments in CASES.items():
            times = bench_engine(engine, segments, repeats)
            results[name][label] = times
            echo(f"| {name} | {describe(engine)} | {label} | {times.seconds:g} | {times.text:.1f} | {times.codes:.1f} |"
                 f" {times.decode:.1f} | {times.total:.1f} | {times.cpu:.1f} |")
    echo("")
    echo("- each request at the model's default guidance (cond + null rows in one batch); seeds 1..N, a warm-up "
         "request first; the stream's sentences are generated for 3 + 3 + 4 s, codes concatenated, decoded once; "
         "a segment longer than the model makes is cut to its longest (s motion); ms CPU: the process's CPU time for "
         "the whole request (all threads), the work without the waiting on a shared machine")
    return results
