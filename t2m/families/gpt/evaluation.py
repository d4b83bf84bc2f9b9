"""The GPT family in `t2m eval`: T2M-GPT's autoregressive sampler (t2m.families.gpt.sampling, the shared GPT loop)."""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

if TYPE_CHECKING:
    from t2m.families.gpt.network import MotionGPT
    from t2m.model.evaluation.evaluate import Models


class GptFamily:
    """Exactly `tokens[i]` codes per text from a MotionGPT (End masked before, forced at, the target)."""

    name = "gpt"
    batch_by_length = False        # rows in the given order: the published tables' draws stay reproducible

    def __init__(self, gpt: MotionGPT, text_encoder: str, path: str) -> None:
        self.gpt = gpt
        self.text_encoder = text_encoder
        self.max_tokens = gpt.config.max_tokens
        self.paths = {"gpt": path}
        self.settings: dict[str, Any] = {}
        self.labels = {"gpt": "GPT"}
        self.joined = "codes concatenated"


    def report_note(self) -> str:
        return ""

    def codes(self, cond: np.ndarray, tokens: Sequence[int], guidance: float, temperature: float,
              top_k: int | None, rng: np.random.Generator) -> list[Any]:
        from t2m.families.gpt.sampling import sample_codes

        return sample_codes(self.gpt, torch.from_numpy(np.asarray(cond, np.float32)), [int(t) for t in tokens],
                            guidance=guidance, temperature=temperature, top_k=top_k, rng=rng)

    def estimate_tokens(self, cond: np.ndarray, rng: np.random.Generator) -> list[int] | None:
        return None


def load_gpt_family(gpt_run: str | Path, codebook_size: int, vq_run: str | Path) -> GptFamily:
    """The GPT run, checked against the VQ's codebook."""
    from t2m.families.gpt.network import MotionGPT
    from t2m.model.training.checkpoint import load_model, read_run_config

    gpt = load_model(gpt_run, expect_kind="gpt")
    assert isinstance(gpt, MotionGPT)
    if gpt.config.codebook_size != codebook_size:
        raise ValueError(f"{gpt_run}: GPT codebook_size {gpt.config.codebook_size} does not match the VQ's "
                         f"nb_code {codebook_size} ({vq_run})")
    text = read_run_config(gpt_run).get("data", {}).get("text_encoder", "minilm")
    return GptFamily(gpt, str(text.get("kind", "minilm") if isinstance(text, dict) else text), str(gpt_run))


def load_gpt_models(evaluator_run: str | Path, vq_run: str | Path, gpt_run: str | Path, data_mean: np.ndarray,
                data_std: np.ndarray) -> Models:
    """The GPT family: evaluator, a 1D VQ and a GPT over its codes."""
    from t2m.model.evaluation.evaluate import code_family_models, load_evaluator_and_vq

    evaluator, vq, mean, std = load_evaluator_and_vq(evaluator_run, vq_run, ["vq"], data_mean, data_std)
    family = load_gpt_family(gpt_run, vq.config.nb_code, vq_run)
    return code_family_models(evaluator, vq, family, mean, std, evaluator_run, vq_run)
