"""A request checked against the model it asks, once for every family: its segments' code steps and its top-k.

Each family's served object turns a request into its own job (t2m.runtime.family_codes), but what a request
may ask of a model is the same for all: a duration becomes round(duration * fps / frames_per_token) steps (at least
1) and must fit the model's longest segment, a null duration lets the model end the segment (when it can), and top-k
must lie within the codebook. Errors are RequestLimitErrors naming the field (a 422 over HTTP)."""
from __future__ import annotations

from typing import TYPE_CHECKING

from t2m.decoding.lockstep import SamplingJob
from t2m.runtime.types import GenerationRequest, ModelLimits, RequestLimitError, tokens_for_duration

if TYPE_CHECKING:
    from t2m.runtime.text import TextEncoder

__all__ = ["check_top_k", "lockstep_job", "segment_steps"]


def segment_steps(request: GenerationRequest, limits: ModelLimits, *, free: str | None = None) -> list[int | None]:
    """Code steps per segment from its duration (None: a null duration); `free` is the reason a null duration is
    refused by this model (None: the model can end a segment itself)."""
    steps: list[int | None] = []
    for index, segment in enumerate(request.segments):
        if segment.duration is None:
            if free is not None:
                raise RequestLimitError(f"segments.{index}.duration", free)
            steps.append(None)
            continue
        target = tokens_for_duration(segment.duration, limits.fps, limits.frames_per_token)
        if target > limits.max_tokens:
            raise RequestLimitError(f"segments.{index}.duration", f"needs {target} tokens, the model makes at most "
                                    f"{limits.max_tokens}")
        steps.append(target)
    return steps


def check_top_k(request: GenerationRequest, limits: ModelLimits) -> None:
    """top_k, when given, is 1..codebook_size."""
    if request.top_k is not None and not 1 <= request.top_k <= limits.codebook_size:
        raise RequestLimitError("top_k", f"must be 1..{limits.codebook_size}, got {request.top_k}")


def lockstep_job(request: GenerationRequest, text: TextEncoder, limits: ModelLimits) -> SamplingJob:
    """A request as a job of the lockstep loops (the GPT's, T2M-HiFiGPT's): a target per segment from its duration
    (None = free length), checked against max_tokens and top_k against the codebook, naming the field."""
    targets = segment_steps(request, limits)
    check_top_k(request, limits)
    conds = text.encode([s.text for s in request.segments])
    return SamplingJob.of(conds, targets, max_tokens=limits.max_tokens, guidance=request.guidance,
                          temperature=request.temperature, top_k=request.top_k, rng=request.seed,
                          cancelled=lambda: request.cancelled)
