"""The masked family in `t2m eval` (MoGenTS / MoMask): token maps from the shared numpy loop.

Generation goes through `t2m.families.masked.sampling.generate_token_maps`, i.e.
`t2m.families.masked.loop.sample_token_maps`
with the modules as its steps: the loop the service runs over the ONNX graphs, so the evaluated recipe (re-masking
schedule, guidance per stage, top-k, temperature, residual layers) is the served one. Each motion is one segment of
its own text and length; a segment's map does not depend on the other segments of the batch (only the order of the
random draws does), so a stream's segments generated here and concatenated are what the service concatenates.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

if TYPE_CHECKING:
    from t2m.families.masked.length_estimator import LengthEstimator
    from t2m.families.masked.masked_transformer import MaskedTransformer
    from t2m.families.masked.residual_transformer import ResidualTransformer
    from t2m.model.evaluation.evaluate import Models
    from t2m.model.networks.joint_vqvae import JointVQVAE
    from t2m.model.networks.vqvae import MotionVQVAE


@dataclass
class MaskedSettings:
    """The masked family's decoding settings besides the first stage's guidance, temperature and top-k (MoMask's
    defaults: 10 steps, residual guidance 5)."""

    steps: int = 10
    residual_guidance: float = 5.0
    residual_top_k: int | None = None

    def check(self) -> None:
        if self.steps < 1:
            raise ValueError(f"steps must be at least 1, got {self.steps}")
        if self.residual_guidance < 0:
            raise ValueError(f"residual guidance must be >= 0, got {self.residual_guidance}")
        if self.residual_top_k is not None and self.residual_top_k < 1:
            raise ValueError(f"residual top-k must be at least 1, got {self.residual_top_k}")


def vq_layout(token_map: np.ndarray, vq: MotionVQVAE | JointVQVAE) -> np.ndarray:
    """A generated map [T, C, R] in the layout the VQ's decoder takes: the map for the joint VQ; [T, R] for a 1D
    residual VQ (MoMask's variant, one column); [T] for a 1D single-layer VQ."""
    from t2m.model.networks.joint_vqvae import JointVQVAE

    if isinstance(vq, JointVQVAE):
        return token_map
    return token_map[:, 0, :] if vq.config.quantizer == "residual" else token_map[:, 0, 0]


class MaskedFamily:
    """Codes of a masked transformer (+ residual transformer, + optional length estimator) for a VQ."""

    name = "masked"
    batch_by_length = True         # each of the ~13 passes runs every map at the batch's longest: ~2x on the test split

    def __init__(self, vq: MotionVQVAE | JointVQVAE, masked: MaskedTransformer, residual: ResidualTransformer | None,
                 length: LengthEstimator | None, text_encoder: str, paths: dict[str, str],
                 settings: MaskedSettings) -> None:
        settings.check()
        self.vq, self.masked, self.residual, self.length = vq, masked, residual, length
        self.text_encoder = text_encoder
        self.max_tokens = min([masked.config.max_tokens] + ([residual.config.max_tokens] if residual else []))
        self.paths = paths
        self.decoding = settings
        self.settings: dict[str, Any] = asdict(settings) | {"residual_stage": residual is not None}
        self.labels = {"masked": "masked transformer", "residual": "residual transformer",
                       "length": "length estimator"}
        self.joined = "token maps concatenated along time"


    def report_note(self) -> str:
        decoding = self.settings
        residual = (f"residual stage guidance {decoding['residual_guidance']:g}, top-k "
                    f"{decoding['residual_top_k'] or 'off'}" if decoding.get("residual_stage")
                    else "no residual stage (first quantiser layer only)")
        return (f"Masked decoding (t2m.families.masked.loop): {decoding['steps']} re-masking steps, the guidance "
                f"below is the masked stage's; {residual}.")

    def codes(self, cond: np.ndarray, tokens: Sequence[int], guidance: float, temperature: float,
              top_k: int | None, rng: np.random.Generator) -> list[Any]:
        from t2m.families.masked.sampling import generate_token_maps

        rows = [int(t) for t in tokens]
        maps = generate_token_maps(self.masked, self.residual, np.asarray(cond, np.float32), rows,
                                   steps=self.decoding.steps, guidance=guidance,
                                   residual_guidance=self.decoding.residual_guidance, top_k=top_k,
                                   residual_top_k=self.decoding.residual_top_k,
                                   temperature=temperature if temperature > 0 else 1.0, rng=rng,
                                   greedy=temperature == 0)
        return [vq_layout(maps[index, :count], self.vq) for index, count in enumerate(rows)]

    @torch.no_grad()
    def estimate_tokens(self, cond: np.ndarray, rng: np.random.Generator) -> list[int] | None:
        """The length estimator's draw per text (at least 1 row, at most what the transformers take)."""
        from t2m.families.masked.length_estimator import sample_length

        if self.length is None:
            return None
        generator = torch.Generator().manual_seed(int(rng.integers(2**62)))
        logits = self.length.eval()(torch.from_numpy(np.asarray(cond, np.float32)))
        drawn = sample_length(logits, generator).clamp(max=self.max_tokens)
        return [int(n) for n in drawn]




def _layers_and_columns(vq: MotionVQVAE | JointVQVAE) -> tuple[int, int]:
    from t2m.model.networks.joint_vqvae import JointVQVAE

    if isinstance(vq, JointVQVAE):
        return vq.config.residual_layers, vq.config.columns
    return (vq.config.residual_layers if vq.config.quantizer == "residual" else 1), 1


def load_masked_family(vq: MotionVQVAE | JointVQVAE, vq_run: str | Path, masked_run: str | Path,
                       residual_run: str | Path | None, length_run: str | Path | None,
                       settings: MaskedSettings) -> MaskedFamily:
    """The masked family's runs, checked against the VQ (codebook, columns, layers) and each other (text)."""
    from t2m.families.masked.length_estimator import LengthEstimator
    from t2m.families.masked.masked_transformer import MaskedTransformer
    from t2m.families.masked.residual_transformer import ResidualTransformer
    from t2m.model.training.checkpoint import check_trained_on, load_run, text_kind

    layers, columns = _layers_and_columns(vq)
    masked = load_run(masked_run, "masked", MaskedTransformer)
    check_trained_on(masked_run, vq_run)
    if (masked.config.codebook_size, masked.config.columns) != (vq.config.nb_code, columns):
        raise ValueError(f"{masked_run}: the masked transformer has {masked.config.codebook_size} codes x "
                         f"{masked.config.columns} columns, the VQ {vq_run} {vq.config.nb_code} x {columns}")
    text = text_kind(masked_run)
    paths = {"masked": str(masked_run)}
    residual = None
    if residual_run is not None:
        residual = load_run(residual_run, "residual", ResidualTransformer)
        check_trained_on(residual_run, vq_run)
        shape = (residual.config.codebook_size, residual.config.columns, residual.config.residual_layers)
        if shape != (vq.config.nb_code, columns, layers):
            raise ValueError(f"{residual_run}: the residual transformer has {shape[0]} codes x {shape[1]} columns x "
                             f"{shape[2]} layers, the VQ {vq_run} {vq.config.nb_code} x {columns} x {layers}")
        if text_kind(residual_run) != text:
            raise ValueError(f"{residual_run}: text encoder {text_kind(residual_run)!r} differs from the masked "
                             f"run's {text!r}")
        paths["residual"] = str(residual_run)
    length = None
    if length_run is not None:
        length = load_run(length_run, "length", LengthEstimator)
        if length.config.text_dim != masked.config.text_dim:
            raise ValueError(f"{length_run}: the length estimator reads {length.config.text_dim}-dim text features, "
                             f"the masked transformer {masked.config.text_dim}")
        paths["length"] = str(length_run)
    return MaskedFamily(vq, masked, residual, length, text, paths, settings)


def load_masked_models(evaluator_run: str | Path, vq_run: str | Path, masked_run: str | Path,
                       residual_run: str | Path | None, length_run: str | Path | None, settings: MaskedSettings,
                       data_mean: np.ndarray, data_std: np.ndarray) -> Models:
    """The masked family: evaluator, the joint VQ (or MoMask's 1D residual VQ), the masked transformer, the residual
    transformer and optionally the length estimator."""
    from t2m.model.evaluation.evaluate import code_family_models, load_evaluator_and_vq

    evaluator, vq, mean, std = load_evaluator_and_vq(evaluator_run, vq_run, ["joint_vq", "vq"], data_mean,
                                                      data_std)
    family = load_masked_family(vq, vq_run, masked_run, residual_run, length_run, settings)
    return code_family_models(evaluator, vq, family, mean, std, evaluator_run, vq_run)
