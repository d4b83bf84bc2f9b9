"""Stand-in engines for testing the HTTP layer (the real OnnxEngine is tested end to end on a bundle elsewhere)."""
from __future__ import annotations

import threading
import time
from collections.abc import Sequence

import numpy as np

from t2m.motion.skeleton import SMPL22
from t2m.runtime.types import (
    GenerationCancelled,
    GenerationRequest,
    ModelLimits,
    Motion,
    SegmentSpan,
    frames_for_duration,
    tokens_for_duration,
)

FAKE_LIMITS = ModelLimits(
    name="fake", version="0.0.1", fps=20, frames_per_token=4, max_tokens=50, codebook_size=64,
    default_guidance=2.5, unconditional_branch=True, length_conditioning=True, skeleton="smpl22",
    joint_names=tuple(SMPL22.joint_names), parents=tuple(SMPL22.parents), ends_segments="its End token")


class FakeEngine:
    """Seeded random-walk joints with the real segment arithmetic; optional delay or gate to simulate slowness."""

    def __init__(self, limits: ModelLimits = FAKE_LIMITS, delay_s: float = 0.0,
                 gate: threading.Event | None = None) -> None:
        self.limits = limits
        self.delay_s = delay_s
        self.gate = gate
        self.batches: list[int] = []

    def generate_batch(self, requests: Sequence[GenerationRequest]) -> list[Motion | BaseException]:
        self.batches.append(len(requests))
        if self.gate is not None:
            self.gate.wait(30)
        deadline = time.perf_counter() + self.delay_s
        while time.perf_counter() < deadline:
            if all(r.cancelled for r in requests):
                break
            time.sleep(0.005)
        return [self._one(r) for r in requests]

    def _one(self, request: GenerationRequest) -> Motion | BaseException:
        if request.cancelled:
            return GenerationCancelled("cancelled")
        rng = np.random.default_rng(request.seed)
        spans, start, tokens = [], 0, 0
        for segment in request.segments:
            steps = (tokens_for_duration(segment.duration) if segment.duration is not None
                     else int(rng.integers(1, self.limits.max_tokens + 1)))
            frames = 4 * steps if segment.duration is None else frames_for_duration(segment.duration)
            spans.append(SegmentSpan(segment.text, start, start + frames))
            start, tokens = start + frames, tokens + steps
        joints = np.asarray(SMPL22.offsets, dtype=np.float32)[None].cumsum(axis=1).repeat(start, 0)
        joints = joints + rng.normal(0, 0.01, joints.shape).astype(np.float32)
        warnings = [] if request.guidance == 1.0 or self.limits.unconditional_branch else ["no unconditional branch"]
        return Motion(joints=joints, fps=20, segments=spans, seed=request.seed, tokens=tokens, warnings=warnings)


class StreamingFakeEngine(FakeEngine):
    """Sends the first `early` frames of each streamed request at once, then takes `delay_s` (cut short by a cancel)
    before returning the motions: a stream that has begun and then fails, times out or is left by its client."""

    def __init__(self, early: int = 8, delay_s: float = 0.0) -> None:
        super().__init__(delay_s=0.0)
        self.early, self.stream_delay_s = early, delay_s
        self.cancelled: list[bool] = []

    def generate_batch(self, requests: Sequence[GenerationRequest]) -> list[Motion | BaseException]:
        motions = super().generate_batch(requests)
        for request, motion in zip(requests, motions):
            if request.on_frames is not None and isinstance(motion, Motion):
                request.on_frames(motion.joints[:self.early])
        deadline = time.perf_counter() + self.stream_delay_s
        while time.perf_counter() < deadline and not all(r.cancelled for r in requests):
            time.sleep(0.005)
        self.cancelled.extend(r.cancelled for r in requests)
        return motions
