"""Tiny random-weight diffusion-family modules and bundles (an MDM and a DiP), for tests: no downloads, seconds."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from t2m.export.graphs.text import TinyTextEncoder
from t2m.export.kit.text_sources import TextSource, tiny_text_source
from t2m.families.diffusion.network import MDM, DiffusionConfig

__all__ = ["TINY_SIZES", "TinyTokenEncoder", "build_random_diffusion_bundle", "random_diffusion_model",
           "random_statistics", "tiny_token_text_source"]

TEXT_DIM, TEXT_MAX_LENGTH = 32, 32
# per arch: the tiny model's config fields (MDM: trans_enc over a pooled text, whole motions of at most max_frames;
# DiP: trans_dec over token states, calls of pred_len frames after context_len)
TINY_SIZES: dict[str, dict[str, Any]] = {
    "mdm": {"arch": "trans_enc", "diffusion_steps": 8, "mask_frames": True},
    "dip": {"arch": "trans_dec", "text_tokens": True, "mask_frames": True, "diffusion_steps": 10,
            "context_len": 8, "pred_len": 16},
}
TINY_MAX_FRAMES = {"mdm": 60, "dip": 200}


class TinyTokenEncoder(TinyTextEncoder):
    """The tiny text encoder's random token embeddings -> linear, per token (zeros at padding), no pooling: a
    token-state encoder's shape, tiny."""

    def forward(self, input_ids: torch.Tensor, attention_mask: torch.Tensor) -> torch.Tensor:
        return self.proj(self.embed(input_ids)) * attention_mask.unsqueeze(-1).to(torch.float32)


def tiny_token_text_source(dim: int = TEXT_DIM, max_length: int = TEXT_MAX_LENGTH, seed: int = 0) -> TextSource:
    """The tiny tokenizer and a TinyTokenEncoder as a token-state text graph (`token_states`)."""
    from t2m.export.graphs.text import build_tiny_tokenizer, export_token_states_graph, tokenize, write_tokenizer

    def write(out_dir: Path) -> dict:
        tokenizer = build_tiny_tokenizer()
        path = write_tokenizer(tokenizer, out_dir / "tokenizer.json", max_length, "[PAD]",
                               tokenizer.token_to_id("[PAD]"))
        encoder = TinyTokenEncoder(tokenizer.get_vocab_size(), dim, seed=seed)
        ids, mask = tokenize(path, ["a person walks", "a man jumps up and down twice"])
        export_token_states_graph(encoder, out_dir / "text_encoder.onnx", ids, mask)
        return {"kind": "tiny-random-tokens", "dim": dim, "max_length": max_length, "pooling": "tokens",
                "normalize": False, "null_condition": "zeros"}

    return TextSource(write)


def random_diffusion_model(arch: str = "mdm", seed: int = 0, **overrides: Any) -> MDM:
    """A tiny random MDM ("mdm") or DiP ("dip") over HumanML3D's 263 features (tests rebuild it from the seed for
    the PyTorch reference)."""
    if arch not in TINY_SIZES:
        raise ValueError(f"arch must be one of {sorted(TINY_SIZES)}, got {arch!r}")
    torch.manual_seed(seed)
    config = DiffusionConfig(**{"features": 263, "latent_dim": 16, "layers": 2, "heads": 2, "ff_size": 32,
                                "dropout": 0.0, "text_dim": TEXT_DIM, "pos_embed_max_len": 256,
                                **TINY_SIZES[arch], **overrides})
    return MDM(config).eval()


def random_statistics(seed: int = 0, features: int = 263) -> tuple[np.ndarray, np.ndarray]:
    """Random mean/std: small means, std in [0.025, 0.075], so random frames decode to finite, moderate motion."""
    rng = np.random.default_rng(seed)
    return (rng.normal(0.0, 0.05, features).astype(np.float32),
            rng.uniform(0.5, 1.5, features).astype(np.float32) * np.float32(0.05))


def build_random_diffusion_bundle(out_dir: str | Path, *, arch: str = "mdm", seed: int = 0,
                                  name: str | None = None, version: str = "0.0.0", join_frames: int = 4,
                                  join_context: int = 4, max_frames: int | None = None, **overrides: Any) -> dict:
    """A tiny random-weight MDM or DiP bundle (the tiny text graph: pooled for MDM, token states for DiP); the
    module is random_diffusion_model(arch, seed, **overrides); `max_frames`: the longest segment (default: 60 MDM,
    200 DiP). Returns the written manifest."""
    from t2m.families.diffusion.export import export_diffusion_bundle

    model = random_diffusion_model(arch, seed, **overrides)
    mean, std = random_statistics(seed)
    text = (tiny_token_text_source(seed=seed) if model.config.text_tokens
            else tiny_text_source(TEXT_DIM, TEXT_MAX_LENGTH, seed=seed))
    return export_diffusion_bundle(
        out_dir, model=model, mean=mean, std=std, text_source=text, name=name or f"t2m-random-{arch}",
        version=version, training_data={"name": "none (random weights)", "license": "Apache-2.0",
                                        "attribution": "Random weights for tests; not a trained model."},
        license="Apache-2.0", default_guidance=2.5 if arch == "mdm" else 7.5,
        max_frames=max_frames or TINY_MAX_FRAMES[arch],
        join_frames=join_frames, join_context=join_context,
        notes="Random weights: this bundle exists to test the service and produces meaningless motion.")
