"""T2M-HiFiGPT in `t2m eval`: code maps [T, R] from the shared loop (t2m.families.hifigpt.loop over the modules, the
loop the service runs over the graphs), decoded by the residual VQ's own `decode`."""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from t2m.families.hifigpt.network import HiFiGPT
    from t2m.model.evaluation.evaluate import Models
    from t2m.model.networks.vqvae import MotionVQVAE


class HiFiGPTFamily:
    """Exactly `tokens[i]` time steps of R codes per text (the stop head is not consulted for a target)."""

    name = "hifigpt"
    batch_by_length = False        # rows in the given order, as the GPT family (finished rows leave the batch)

    def __init__(self, model: HiFiGPT, text_encoder: str, path: str) -> None:
        self.model = model
        self.text_encoder = text_encoder
        self.max_tokens = model.config.max_tokens
        self.paths = {"hifigpt": path}
        self.settings: dict[str, Any] = {"depth": model.config.depth}
        self.labels = {"hifigpt": "double-tier GPT"}
        self.joined = "codes concatenated"


    def report_note(self) -> str:
        return (f"T2M-HiFiGPT decoding (t2m.families.hifigpt.loop): {self.settings['depth']} residual depths per time "
                "step, guidance on the code logits (the stop head is not consulted at the crops' lengths).")

    def codes(self, cond: np.ndarray, tokens: Sequence[int], guidance: float, temperature: float,
              top_k: int | None, rng: np.random.Generator) -> list[Any]:
        from t2m.families.hifigpt.sampling import sample_code_maps

        return sample_code_maps(self.model, np.asarray(cond, np.float32), [int(t) for t in tokens],
                                guidance=guidance, temperature=temperature, top_k=top_k, rng=rng)

    def estimate_tokens(self, cond: np.ndarray, rng: np.random.Generator) -> list[int] | None:
        return None


def load_hifigpt_family(hifigpt_run: str | Path, vq: MotionVQVAE, vq_run: str | Path) -> HiFiGPTFamily:
    """The HiFiGPT run, checked against the VQ (codebook, depth, code_dim) and the VQ it was trained on."""
    from t2m.families.hifigpt.network import HiFiGPT, check_fits_vq
    from t2m.model.training.checkpoint import check_trained_on, load_run, text_kind

    model = load_run(hifigpt_run, "hifigpt", HiFiGPT)
    check_trained_on(hifigpt_run, vq_run)
    check_fits_vq(model.config, vq.config.to_dict(), (f"{hifigpt_run}: the HiFiGPT", f"the VQ {vq_run}"))
    return HiFiGPTFamily(model, text_kind(hifigpt_run), str(hifigpt_run))


def load_hifigpt_models(evaluator_run: str | Path, vq_run: str | Path, hifigpt_run: str | Path,
                        data_mean: np.ndarray, data_std: np.ndarray) -> Models:
    """T2M-HiFiGPT: evaluator, a residual 1D VQ and the double-tier GPT over its code maps."""
    from t2m.model.evaluation.evaluate import code_family_models, load_evaluator_and_vq
    from t2m.model.networks.vqvae import MotionVQVAE

    evaluator, vq, mean, std = load_evaluator_and_vq(evaluator_run, vq_run, ["vq"], data_mean, data_std)
    assert isinstance(vq, MotionVQVAE), "a vq run rebuilds a MotionVQVAE"
    family = load_hifigpt_family(hifigpt_run, vq, vq_run)
    return code_family_models(evaluator, vq, family, mean, std, evaluator_run, vq_run)
