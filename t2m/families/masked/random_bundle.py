"""Tiny random-weight masked-family modules and bundles, for tests (no training run, no downloads)."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from t2m.export.kit.text_sources import tiny_text_source
from t2m.model.networks.vqvae import MotionVQVAE, VQConfig

__all__ = ['build_random_masked_bundle', 'random_masked_models']


def random_masked_models(*, variant: str = "2d", codebook_size: int = 16, residual_layers: int = 2,
                         length_estimator: bool = True, text_dim: int = 32, max_tokens: int = 50,
                         seed: int = 0) -> dict[str, Any]:
    """Tiny random modules of the masked family: {vq, masked, residual (None with one layer), length (or None),
    mean, std}. variant "2d": a joint VQ (MoGenTS; 6 token columns); "1d": a 1D VQ (MoMask; one column)."""
    from t2m.families.masked.length_estimator import LengthEstimator, LengthEstimatorConfig
    from t2m.families.masked.masked_transformer import MaskedTransformer
    from t2m.families.masked.residual_transformer import ResidualTransformer
    from t2m.model.networks.joint_vqvae import JointVQConfig, JointVQVAE
    from t2m.model.networks.token_transformer import TokenTransformerConfig

    torch.manual_seed(seed)
    vq: JointVQVAE | MotionVQVAE
    if variant == "2d":
        vq = JointVQVAE(JointVQConfig(width=16, code_dim=16, nb_code=codebook_size, depth=1,
                                      residual_layers=residual_layers))
        columns, positional = vq.config.columns, "2d"
    elif variant == "1d":
        quantizer = "residual" if residual_layers > 1 else "ema_reset"
        vq = MotionVQVAE(VQConfig(width=16, code_dim=16, nb_code=codebook_size, depth=1, quantizer=quantizer,
                                  residual_layers=residual_layers))
        columns, positional = 1, "1d"
    else:
        raise ValueError(f"variant must be '2d' or '1d', got {variant!r}")
    one_d = positional == "1d"
    config = TokenTransformerConfig(codebook_size=codebook_size, columns=columns, residual_layers=residual_layers,
                                    max_tokens=max_tokens, latent=16, n_head=2, n_layer=1, ff_size=32, dropout=0.0,
                                    text_dim=text_dim, code_dim=16, positional=positional,
                                    spatial_attention=not one_d, temporal_attention=not one_d)
    masked = MaskedTransformer(config).eval()
    residual = ResidualTransformer(config).eval() if residual_layers > 1 else None
    length = (LengthEstimator(LengthEstimatorConfig(text_dim=text_dim, hidden=16, max_tokens=max_tokens,
                                                    dropout=0.0)).eval() if length_estimator else None)
    rng = np.random.default_rng(seed)
    mean = rng.normal(0.0, 0.1, vq.config.feat_dim).astype(np.float32)
    std = rng.uniform(0.5, 1.5, vq.config.feat_dim).astype(np.float32)
    return {"vq": vq.eval(), "masked": masked, "residual": residual, "length": length, "mean": mean, "std": std}


def build_random_masked_bundle(
    out_dir: str | Path,
    *,
    variant: str = "2d",
    codebook_size: int = 16,
    residual_layers: int = 2,
    length_estimator: bool = True,
    text_dim: int = 32,
    text_max_length: int = 32,
    max_tokens: int = 50,
    steps: int = 4,
    guidance: float = 4.0,
    residual_guidance: float = 5.0,
    check_parity: bool = False,
    seed: int = 0,
    name: str = "t2m-random-masked-test",
    version: str = "0.0.0",
    encoder: bool = True,
) -> Path:
    """A tiny random-weight masked-family bundle (service tests), with the tiny text graph: a few seconds.

    The modules are random_masked_models(...) with the same arguments (tests rebuild them for the PyTorch
    reference). residual_layers 1 gives no residual.onnx; length_estimator False no length.onnx. Returns ``out_dir``.
    """
    from t2m.families.masked.export import MaskedDecoding, export_masked_bundle

    models = random_masked_models(variant=variant, codebook_size=codebook_size, residual_layers=residual_layers,
                                  length_estimator=length_estimator, text_dim=text_dim, max_tokens=max_tokens,
                                  seed=seed)
    export_masked_bundle(
        out_dir, **models, text_source=tiny_text_source(text_dim, text_max_length, seed=seed), name=name,
        version=version, training_data={"name": "none (random weights)", "license": "Apache-2.0",
                                        "attribution": "Random weights for tests; not a trained model."},
        license="Apache-2.0", decoding=MaskedDecoding(steps=steps, guidance=guidance,
                                                      residual_guidance=residual_guidance),
        notes="Random weights: this bundle exists to test the service and produces meaningless motion.",
        check_parity=check_parity, encoder=encoder)
    return Path(out_dir)
