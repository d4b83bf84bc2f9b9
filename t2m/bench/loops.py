"""The decoding loops driven alone for the speed benchmarks: B one-segment jobs of fixed length with guidance on, over
whatever steps are given (onnxruntime sessions, PyTorch modules, or steps that answer instantly), returning the
codes a decoder reads. The host-loop benchmark (`t2m bench host-loop`) and the GPU suite (benchmarks/gpu_suite.py)
time the same loops this way."""
from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

Generate = Callable[[int], np.ndarray]      # batch -> codes ready for decoder.onnx


def _conds(batch: int, dim: int) -> np.ndarray:
    return np.random.default_rng(batch).normal(size=(batch, dim)).astype(np.float32)


def gpt_generate(step: Any, dim: int, tokens: int, max_tokens: int, end_id: int) -> Generate:
    """B one-segment jobs of `tokens` codes with guidance 3, one GptCohort: codes [B, tokens]."""
    from t2m.families.gpt.loop import GptCohort, SamplingJob

    def generate(batch: int) -> np.ndarray:
        jobs = [SamplingJob.of(cond[None], [tokens], max_tokens=max_tokens, guidance=3.0, rng=index)
                for index, cond in enumerate(_conds(batch, dim))]
        return np.stack([codes[0] for codes in GptCohort(step, jobs, max_tokens, end_id).run()])  # type: ignore[index]
    return generate


def hifigpt_generate(temporal: Any, residual: Any, dim: int, steps: int, max_tokens: int) -> Generate:
    """B one-segment jobs of `steps` time steps with guidance 3, one HiFiGPTCohort: codes [B, steps, R]."""
    from t2m.decoding.lockstep import SamplingJob
    from t2m.families.hifigpt.loop import HiFiGPTCohort

    def generate(batch: int) -> np.ndarray:
        jobs = [SamplingJob.of(cond[None], [steps], max_tokens=max_tokens, guidance=3.0, rng=index)
                for index, cond in enumerate(_conds(batch, dim))]
        result = HiFiGPTCohort(temporal, residual, jobs, max_tokens).run()
        return np.stack([codes[0] for codes in result])  # type: ignore[index]
    return generate


def masked_generate(masked: Any, residual: Any, dim: int, rows: int, passes: int,
                    decoding: dict[str, Any]) -> Generate:
    """B one-segment jobs of `rows` token rows, `passes` mask steps, the model's guidance and top-k (`decoding`:
    MaskedJob's fields): maps [B, rows, C, R]."""
    from t2m.families.masked.loop import MaskedJob, sample_token_maps

    def generate(batch: int) -> np.ndarray:
        jobs = [MaskedJob(conds=cond[None], rows=[rows], rng=np.random.default_rng(index), steps=passes, **decoding)
                for index, cond in enumerate(_conds(batch, dim))]
        return np.stack([maps[0] for maps in sample_token_maps(masked, residual, jobs)])  # type: ignore[index]
    return generate


def momask_release_decoding(codebook: int) -> dict[str, Any]:
    """MoMask's release decoding (its HumanML3D evaluation settings: guidance 4 and 5, top-k 10% of each stage's
    classes, the residual stage at temperature 1), as MaskedJob fields."""
    from dataclasses import asdict

    from t2m.families.masked.import_momask import release_decoding

    fields = asdict(release_decoding("t2m", codebook))
    return {name: fields[name] for name in ("guidance", "residual_guidance", "top_k", "residual_top_k",
                                            "residual_temperature")}
