"""A tiny random-weight GPT-family bundle in about a second, for tests of the service (no training run, no
downloads)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from t2m.export.kit.text_sources import minilm_text_source, tiny_text_source
from t2m.families.gpt.export import export_bundle
from t2m.families.gpt.network import GPTConfig, MotionGPT
from t2m.model.networks.vqvae import MotionVQVAE, VQConfig

__all__ = ['build_random_bundle']


def build_random_bundle(
    out_dir: str | Path,
    *,
    codebook_size: int = 32,
    embed: int = 32,
    n_head: int = 2,
    n_layer: int = 2,
    block_size: int = 51,
    text_dim: int = 32,
    text_max_length: int = 32,
    text_encoder: str = "tiny",
    length_conditioning: bool = True,
    unconditional_branch: bool = True,
    default_guidance: float = 3.0,
    vq_width: int = 32,
    code_dim: int = 16,
    residual_layers: int = 1,
    int8: str = "none",
    seed: int = 0,
    name: str = "t2m-random-test",
    version: str = "0.0.0",
    encoder: bool = True,
    fixed_step: bool = False,
) -> Path:
    """A tiny random-weight bundle that satisfies the contract (for service tests): ~1 s with the tiny text graph.

    text_encoder: "tiny" (random embeddings + a WordPiece tokenizer trained on a few sentences, dim = text_dim)
    or "minilm" (the real all-MiniLM-L6-v2 from the offline package; text_dim becomes 384; ~10 s more).
    residual_layers > 1 gives a residual-VQ decoder with input codes [B, T, R].
    fixed_step adds gpt_step_fixed.onnx (the step T2M_CUDA_GRAPHS replays).
    Deterministic for a given seed. Returns ``out_dir``.
    """
    torch.manual_seed(seed)
    if text_encoder == "tiny":
        text_source = tiny_text_source(text_dim, text_max_length, seed=seed)
    elif text_encoder == "minilm":
        text_source = minilm_text_source()
        text_dim = 384
    else:
        raise ValueError(f"text_encoder must be 'tiny' or 'minilm', got {text_encoder!r}")
    quantizer = "residual" if residual_layers > 1 else "ema_reset"
    vq = MotionVQVAE(VQConfig(width=vq_width, code_dim=code_dim, nb_code=codebook_size, depth=1,
                              quantizer=quantizer, residual_layers=residual_layers))
    half = n_layer // 2
    gpt = MotionGPT(GPTConfig(codebook_size=codebook_size, embed=embed, n_head=n_head, n_layer_base=n_layer - half,
                              n_layer_head=half, block_size=block_size, text_dim=text_dim,
                              length_conditioning=length_conditioning))
    rng = np.random.default_rng(seed)
    mean = rng.normal(0.0, 0.1, vq.config.feat_dim).astype(np.float32)
    std = rng.uniform(0.5, 1.5, vq.config.feat_dim).astype(np.float32)
    export_bundle(
        out_dir,
        vq=vq,
        gpt=gpt,
        mean=mean,
        std=std,
        text_source=text_source,
        name=name,
        version=version,
        unconditional_branch=unconditional_branch,
        default_guidance=default_guidance,
        training_data={"name": "none (random weights)", "license": "Apache-2.0",
                       "attribution": "Random weights for tests; not a trained model."},
        license="Apache-2.0",
        int8=int8,
        notes="Random weights: this bundle exists to test the service and produces meaningless motion.",
        encoder=encoder,
        fixed_step=fixed_step,
    )
    return Path(out_dir)
