"""T2M-HiFiGPT's codes for the engine: per segment a code map [steps, R] from temporal_step.onnx and residual_step.onnx
through t2m.families.hifigpt.loop, every segment of every request stepping in lockstep, each request drawing from its
own
seeded generator.

Requests become jobs exactly as for the GPT family (t2m.runtime.requests.lockstep_job): a duration gives
round(duration * fps / frames_per_token) steps, a null duration lets the stop head end the segment; `guidance`
applies to the code logits and to the stop logits, `temperature` and `top_k` to the code draws (temperature also to
the stop probability).
"""
from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from t2m.decoding.lockstep import SamplingJob
from t2m.families.hifigpt.loop import HiFiGPTCohort, sample_code_rows
from t2m.runtime.bound_step import BoundResidualGptStep, BoundTemporalStep
from t2m.runtime.bundle_loader import Bundle
from t2m.runtime.onnx_step import OnnxResidualGptStep, OnnxTemporalStep
from t2m.runtime.requests import lockstep_job
from t2m.runtime.text import TextEncoder
from t2m.runtime.types import CodeLayout, GenerationRequest, ModelLimits

__all__ = ["HiFiGPTCodes"]


class HiFiGPTCodes:
    """Requests -> per-segment code maps [steps, R] with the bundle's two step graphs (their caches kept on the
    device when the bundle's execution binds: engine/bound_step.py)."""

    ends_segments = "its stop head"

    def __init__(self, bundle: Bundle) -> None:
        manifest = bundle.manifest
        block = manifest.settings  # t2m.families.hifigpt.family.HiFiGPTSettings
        binds = bundle.execution.binds
        temporal_class = BoundTemporalStep if binds else OnnxTemporalStep
        residual_class = BoundResidualGptStep if binds else OnnxResidualGptStep
        self.temporal = temporal_class(bundle.sessions["temporal_step.onnx"], manifest.residual_layers,
                                       block.n_layer_temporal, block.n_head, block.head_dim,
                                       block.length_conditioning)
        self.residual = residual_class(bundle.sessions["residual_step.onnx"], block.n_layer_residual,
                                       block.n_head, block.head_dim)
        self.code_layout = CodeLayout((manifest.residual_layers,), (manifest.codebook_size,))   # a row of R codes

    def job(self, request: GenerationRequest, text: TextEncoder, limits: ModelLimits) -> SamplingJob:
        return lockstep_job(request, text, limits)

    def sample(self, jobs: Sequence[SamplingJob], max_tokens: int,
               on_step: Callable[[int], None] | None) -> list[list[np.ndarray] | None]:
        return sample_code_rows(self.temporal, self.residual, jobs, max_tokens, on_step)

    def cohort(self, jobs: Sequence[SamplingJob], max_tokens: int) -> HiFiGPTCohort:
        """Jobs that start stepping together now (continuous batching: t2m.runtime.continuous)."""
        return HiFiGPTCohort(self.temporal, self.residual, jobs, max_tokens)
