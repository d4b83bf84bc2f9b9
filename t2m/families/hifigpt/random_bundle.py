"""Tiny random-weight T2M-HiFiGPT modules and bundles, for tests (no training run, no downloads)."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from t2m.export.kit.text_sources import tiny_text_source
from t2m.model.networks.vqvae import MotionVQVAE, VQConfig

__all__ = ['build_random_hifigpt_bundle', 'random_hifigpt_models']


def random_hifigpt_models(*, codebook_size: int = 16, depth: int = 3, shared_codebook: bool = True,
                          frames_per_token: int = 8, text_dim: int = 32, max_tokens: int = 25,
                          length_conditioning: bool = True, causal_decoder_blocks: bool = False,
                          seed: int = 0) -> dict[str, Any]:
    """Tiny random modules of T2M-HiFiGPT: {vq (residual, `frames_per_token` frames a code; a short-lookahead decoder
    with `causal_decoder_blocks`), model (its codebooks the VQ's), mean, std}."""
    from t2m.families.hifigpt.network import HiFiGPT, HiFiGPTConfig, vq_codebooks, vq_fields

    torch.manual_seed(seed)
    vq = MotionVQVAE(VQConfig(width=16, code_dim=16, nb_code=codebook_size, down_t=frames_per_token.bit_length() - 1,
                              depth=1, quantizer="residual", residual_layers=depth, shared_codebook=shared_codebook,
                              causal_decoder_blocks=causal_decoder_blocks)).eval()
    model = HiFiGPT(HiFiGPTConfig(**vq_fields(vq.config.to_dict()), embed=32, n_head=2, n_layer_temporal=2,
                                  n_layer_residual=1, max_tokens=max_tokens, text_dim=text_dim, dropout=0.0,
                                  length_conditioning=length_conditioning)).eval()
    model.set_codebooks(vq_codebooks(vq))
    rng = np.random.default_rng(seed)
    mean = rng.normal(0.0, 0.1, vq.config.feat_dim).astype(np.float32)
    std = rng.uniform(0.5, 1.5, vq.config.feat_dim).astype(np.float32)
    return {"vq": vq, "model": model, "mean": mean, "std": std}


def build_random_hifigpt_bundle(
    out_dir: str | Path,
    *,
    codebook_size: int = 16,
    depth: int = 3,
    shared_codebook: bool = True,
    frames_per_token: int = 8,
    text_dim: int = 32,
    text_max_length: int = 32,
    max_tokens: int = 25,
    length_conditioning: bool = True,
    causal_decoder_blocks: bool = False,
    default_guidance: float = 3.0,
    check_parity: bool = False,
    seed: int = 0,
    name: str = "t2m-random-hifigpt-test",
    version: str = "0.0.0",
    encoder: bool = True,
) -> Path:
    """A tiny random-weight T2M-HiFiGPT bundle (service tests), with the tiny text graph: a second or two. The modules
    are random_hifigpt_models(...) with the same arguments (tests rebuild them for the PyTorch reference)."""
    from t2m.families.hifigpt.export import export_hifigpt_bundle

    models = random_hifigpt_models(codebook_size=codebook_size, depth=depth, shared_codebook=shared_codebook,
                                   frames_per_token=frames_per_token, text_dim=text_dim, max_tokens=max_tokens,
                                   length_conditioning=length_conditioning,
                                   causal_decoder_blocks=causal_decoder_blocks, seed=seed)
    export_hifigpt_bundle(
        out_dir, **models, text_source=tiny_text_source(text_dim, text_max_length, seed=seed), name=name,
        version=version, training_data={"name": "none (random weights)", "license": "Apache-2.0",
                                        "attribution": "Random weights for tests; not a trained model."},
        license="Apache-2.0", default_guidance=default_guidance,
        notes="Random weights: this bundle exists to test the service and produces meaningless motion.",
        check_parity=check_parity, encoder=encoder)
    return Path(out_dir)
