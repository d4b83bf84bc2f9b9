"""The GPT family's codes for the engine: one code per step from gpt_step.onnx (t2m.families.gpt.loop), End-terminated
free-length segments, all requests' segments stepped in lockstep."""
from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from t2m.bundle.graphs import FIXED_STEP_GRAPH
from t2m.families.gpt.loop import GptCohort, GptStep, SamplingJob, sample_codes
from t2m.runtime.bound_step import BoundGptStep
from t2m.runtime.bundle_loader import Bundle
from t2m.runtime.graphed_step import FixedCacheGptStep
from t2m.runtime.onnx_step import OnnxGptStep
from t2m.runtime.requests import lockstep_job
from t2m.runtime.text import TextEncoder
from t2m.runtime.types import CodeLayout, GenerationRequest, ModelLimits

__all__ = ["GptCodes"]


class GptCodes:
    """Requests -> per-segment code sequences [n] with the bundle's GPT step graph (its cache kept on the device
    when the bundle's execution binds: engine/bound_step.py), or with T2M_CUDA_GRAPHS and a bundle carrying
    gpt_step_fixed.onnx, the fixed-capacity step replayed as CUDA graphs (engine/graphed_step.py)."""

    ends_segments = "its End token"

    def __init__(self, bundle: Bundle) -> None:
        gpt = bundle.manifest.settings  # t2m.families.gpt.family.GptSettings
        self.step: GptStep
        fixed = bundle.sessions.get(FIXED_STEP_GRAPH)   # opened only with T2M_CUDA_GRAPHS (engine/bundle.py)
        if fixed is not None:
            self.step = FixedCacheGptStep(fixed, gpt.n_layer, gpt.n_head, gpt.head_dim, gpt.block_size,
                                          gpt.length_conditioning, cuda_graph=bundle.execution.on_gpu)
        else:
            step_class = BoundGptStep if bundle.execution.binds else OnnxGptStep
            self.step = step_class(bundle.sessions["gpt_step.onnx"], gpt.n_layer, gpt.n_head, gpt.head_dim,
                                   gpt.length_conditioning)
        self.end_id = gpt.end_id
        self.code_layout = CodeLayout((), (bundle.manifest.codebook_size,))   # one code per step (End excluded)

    def job(self, request: GenerationRequest, text: TextEncoder, limits: ModelLimits) -> SamplingJob:
        return lockstep_job(request, text, limits)

    def sample(self, jobs: Sequence[SamplingJob], max_tokens: int,
               on_step: Callable[[int], None] | None) -> list[list[np.ndarray] | None]:
        return sample_codes(self.step, jobs, max_tokens, self.end_id, on_step)

    def cohort(self, jobs: Sequence[SamplingJob], max_tokens: int) -> GptCohort:
        """Jobs that start stepping together now (continuous batching: t2m.runtime.continuous)."""
        return GptCohort(self.step, jobs, max_tokens, self.end_id)
