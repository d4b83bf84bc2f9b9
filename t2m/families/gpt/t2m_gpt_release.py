"""Checkpoints written with EXACTLY the key names of the released T2M-GPT files (../shared/docs/t2m-gpt-checkpoints.md),
built from that table - not from our modules - with random values and optionally scaled-down sizes."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

RELEASE_VQ = {"feat_dim": 263, "width": 512, "code_dim": 512, "nb_code": 512, "down_t": 2, "depth": 3}
RELEASE_GPT = {"codebook": 512, "embed": 1024, "layers": (9, 9), "block": 51, "text_dim": 512, "ff_rate": 4}


def _conv(state: dict, key: str, out_ch: int, in_ch: int, kernel: int, g: torch.Generator) -> None:
    state[f"{key}.weight"] = torch.randn(out_ch, in_ch, kernel, generator=g) / (in_ch * kernel) ** 0.5
    state[f"{key}.bias"] = torch.randn(out_ch, generator=g) * 0.01


def release_vq_state(feat_dim=263, width=512, code_dim=512, nb_code=512, down_t=2, depth=3, seed=0) -> dict:
    """The 'net' dict of net_last.pth: 'vqvae.'-prefixed encoder/decoder convs and the quantizer.codebook buffer."""
    g = torch.Generator().manual_seed(seed)
    s: dict[str, torch.Tensor] = {}
    _conv(s, "vqvae.encoder.model.0", width, feat_dim, 3, g)
    for i in range(2, 2 + down_t):
        _conv(s, f"vqvae.encoder.model.{i}.0", width, width, 4, g)
        for j in range(depth):
            _conv(s, f"vqvae.encoder.model.{i}.1.model.{j}.conv1", width, width, 3, g)
            _conv(s, f"vqvae.encoder.model.{i}.1.model.{j}.conv2", width, width, 1, g)
    _conv(s, f"vqvae.encoder.model.{2 + down_t}", code_dim, width, 3, g)
    _conv(s, "vqvae.decoder.model.0", width, code_dim, 3, g)
    for i in range(2, 2 + down_t):
        for j in range(depth):
            _conv(s, f"vqvae.decoder.model.{i}.0.model.{j}.conv1", width, width, 3, g)
            _conv(s, f"vqvae.decoder.model.{i}.0.model.{j}.conv2", width, width, 1, g)
        _conv(s, f"vqvae.decoder.model.{i}.2", width, width, 3, g)
    _conv(s, f"vqvae.decoder.model.{2 + down_t}", width, width, 3, g)
    _conv(s, f"vqvae.decoder.model.{4 + down_t}", feat_dim, width, 3, g)
    s["vqvae.quantizer.codebook"] = torch.randn(nb_code, code_dim, generator=g)
    return s


def release_gpt_state(codebook=512, embed=1024, layers=(9, 9), block=51, text_dim=512, ff_rate=4, seed=0,
                      std=0.02) -> dict:
    """The 'trans' dict of net_best_fid.pth: trans_base / trans_head with attn.mask buffers and pos_embedding."""
    g = torch.Generator().manual_seed(seed)

    def rand(*shape: int, scale: float = std) -> torch.Tensor:
        return torch.randn(*shape, generator=g) * scale

    s: dict[str, torch.Tensor] = {
        "trans_base.tok_emb.weight": rand(codebook + 2, embed),
        "trans_base.cond_emb.weight": rand(embed, text_dim),
        "trans_base.cond_emb.bias": rand(embed),
        "trans_base.pos_embedding.weight": rand(block, embed),
    }
    position = np.arange(block)[:, None] / np.power(10000, np.arange(0, embed, 2) / embed)[None]
    table = np.zeros((block, embed), np.float32)
    table[:, 0::2], table[:, 1::2] = np.sin(position), np.cos(position)
    s["trans_base.pos_embed.embed"] = torch.from_numpy(table)[:, None, :]
    for part, count in (("trans_base", layers[0]), ("trans_head", layers[1])):
        for i in range(count):
            p = f"{part}.blocks.{i}"
            for ln in ("ln1", "ln2"):
                s[f"{p}.{ln}.weight"] = 1 + rand(embed, scale=0.1)
                s[f"{p}.{ln}.bias"] = rand(embed)
            for proj in ("key", "query", "value", "proj"):
                s[f"{p}.attn.{proj}.weight"] = rand(embed, embed)
                s[f"{p}.attn.{proj}.bias"] = rand(embed)
            s[f"{p}.attn.mask"] = torch.tril(torch.ones(block, block)).view(1, 1, block, block)
            s[f"{p}.mlp.0.weight"] = rand(ff_rate * embed, embed)
            s[f"{p}.mlp.0.bias"] = rand(ff_rate * embed)
            s[f"{p}.mlp.2.weight"] = rand(embed, ff_rate * embed)
            s[f"{p}.mlp.2.bias"] = rand(embed)
    s["trans_head.ln_f.weight"] = 1 + rand(embed, scale=0.1)
    s["trans_head.ln_f.bias"] = rand(embed)
    s["trans_head.head.weight"] = rand(codebook + 1, embed)
    return s


def write_release_files(directory: Path, vq: dict, gpt: dict, feat_dim: int = 263, seed: int = 0) -> dict[str, Path]:
    """net_last.pth, net_best_fid.pth, mean.npy, std.npy as the release lays them out."""
    directory.mkdir(parents=True, exist_ok=True)
    paths = {name: directory / name for name in ("net_last.pth", "net_best_fid.pth", "mean.npy", "std.npy")}
    torch.save({"net": vq}, paths["net_last.pth"])
    torch.save({"trans": gpt}, paths["net_best_fid.pth"])
    rng = np.random.default_rng(seed)
    np.save(paths["mean.npy"], rng.normal(size=feat_dim).astype(np.float32))
    np.save(paths["std.npy"], rng.uniform(0.1, 1.0, size=feat_dim).astype(np.float32))
    return paths
