"""Random-weight checkpoints in EXACTLY the layout of MoMask's release (../shared/docs/masked-models.md §1.5):
folder names under ``checkpoints/t2m/``, top-level keys (optimizer and scheduler entries in latest.tar), state-dict
key names and shapes. Built from that table, not from our modules, so the importer's strict loads test the layout.

Sizes are parameters: the release's (``RELEASE``) in the slow test, small ones in the default suite.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

VQ_DIR = "rvq_nq6_dc512_nc512_noshare_qdp0.2"
MASKED_DIR = "t2m_nlayer8_nhead6_ld384_ff1024_cdp0.1_rvq6ns"
RESIDUAL_DIR = "tres_nlayer8_ld384_ff1024_rvq6ns_cdp0.2_sw"
LENGTH_DIR = "length_estimator"


@dataclass(frozen=True)
class MomaskSizes:
    """Every size of the release's four networks (the release: ``RELEASE``)."""

    feat_dim: int = 263
    width: int = 512            # VQ conv width
    code_dim: int = 512
    nb_code: int = 512
    quantizers: int = 6
    latent: int = 384
    heads: int = 6
    layers: int = 8
    ff: int = 1024
    text_dim: int = 512
    pe_rows: int = 5000
    length_hidden: int = 512
    length_classes: int = 50


RELEASE = MomaskSizes()
SMALL = MomaskSizes(width=32, code_dim=32, nb_code=64, latent=48, heads=6, layers=2, ff=64, pe_rows=300,
                    length_hidden=32)


class _Random:
    def __init__(self, seed: int, std: float) -> None:
        self.g = torch.Generator().manual_seed(seed)
        self.std = std

    def __call__(self, *shape: int, scale: float | None = None) -> torch.Tensor:
        return torch.randn(*shape, generator=self.g) * (self.std if scale is None else scale)


def _conv(state: dict, key: str, out_ch: int, in_ch: int, kernel: int, rand: _Random) -> None:
    state[f"{key}.weight"] = rand(out_ch, in_ch, kernel, scale=1 / math.sqrt(in_ch * kernel))
    state[f"{key}.bias"] = rand(out_ch, scale=0.01)


def vq_state(s: MomaskSizes, seed: int = 0) -> dict[str, torch.Tensor]:
    """'vq_model': encoder.* / decoder.* convs (dilations are not stored) and quantizer.layers.{i}.codebook."""
    rand, state = _Random(seed, 1.0), dict[str, torch.Tensor]()
    w = s.width
    _conv(state, "encoder.model.0", w, s.feat_dim, 3, rand)
    for i in (2, 3):
        _conv(state, f"encoder.model.{i}.0", w, w, 4, rand)
        for j in range(3):
            _conv(state, f"encoder.model.{i}.1.model.{j}.conv1", w, w, 3, rand)
            _conv(state, f"encoder.model.{i}.1.model.{j}.conv2", w, w, 1, rand)
    _conv(state, "encoder.model.4", s.code_dim, w, 3, rand)
    _conv(state, "decoder.model.0", w, s.code_dim, 3, rand)
    for i in (2, 3):
        for j in range(3):
            _conv(state, f"decoder.model.{i}.0.model.{j}.conv1", w, w, 3, rand)
            _conv(state, f"decoder.model.{i}.0.model.{j}.conv2", w, w, 1, rand)
        _conv(state, f"decoder.model.{i}.2", w, w, 3, rand)
    _conv(state, "decoder.model.4", w, w, 3, rand)
    _conv(state, "decoder.model.6", s.feat_dim, w, 3, rand)
    for q in range(s.quantizers):
        state[f"quantizer.layers.{q}.codebook"] = rand(s.nb_code, s.code_dim)
    return state


def sinusoid_pe(rows: int, dim: int) -> torch.Tensor:
    """[rows, 1, dim]: pe[p, 2k] = sin(p 10000^(-2k/dim)), pe[p, 2k+1] = cos(...) (the release's buffer)."""
    position = torch.arange(rows, dtype=torch.float32)[:, None]
    frequency = torch.exp(torch.arange(0, dim, 2, dtype=torch.float32) * (-math.log(10000.0) / dim))
    pe = torch.zeros(rows, dim)
    pe[:, 0::2], pe[:, 1::2] = torch.sin(position * frequency), torch.cos(position * frequency)
    return pe[:, None, :]


def _encoder_layers(state: dict, s: MomaskSizes, rand: _Random) -> None:
    d = s.latent
    for i in range(s.layers):
        p = f"seqTransEncoder.layers.{i}"
        state |= {
            f"{p}.self_attn.in_proj_weight": rand(3 * d, d), f"{p}.self_attn.in_proj_bias": rand(3 * d),
            f"{p}.self_attn.out_proj.weight": rand(d, d), f"{p}.self_attn.out_proj.bias": rand(d),
            f"{p}.linear1.weight": rand(s.ff, d), f"{p}.linear1.bias": rand(s.ff),
            f"{p}.linear2.weight": rand(d, s.ff), f"{p}.linear2.bias": rand(d),
            f"{p}.norm1.weight": 1 + rand(d, scale=0.1), f"{p}.norm1.bias": rand(d),
            f"{p}.norm2.weight": 1 + rand(d, scale=0.1), f"{p}.norm2.bias": rand(d),
        }


def _shared(state: dict, s: MomaskSizes, rand: _Random, pe_noise: float, head_out: int) -> None:
    """The keys both transformers have: input_process, position_enc.pe, the encoder, cond_emb, output_process."""
    d = s.latent
    state["input_process.poseEmbedding.weight"] = rand(d, s.code_dim)
    state["input_process.poseEmbedding.bias"] = rand(d)
    state["position_enc.pe"] = sinusoid_pe(s.pe_rows, d) + rand(s.pe_rows, 1, d, scale=pe_noise)
    _encoder_layers(state, s, rand)
    state["cond_emb.weight"], state["cond_emb.bias"] = rand(d, s.text_dim), rand(d)
    state["output_process.dense.weight"], state["output_process.dense.bias"] = rand(d, d), rand(d)
    state["output_process.LayerNorm.weight"] = 1 + rand(d, scale=0.1)
    state["output_process.LayerNorm.bias"] = rand(d)
    state["output_process.poseFinal.weight"], state["output_process.poseFinal.bias"] = rand(head_out, d), rand(head_out)


def masked_state(s: MomaskSizes, seed: int = 1, std: float = 0.05, pe_noise: float = 0.0) -> dict[str, torch.Tensor]:
    """'t2m_transformer' (108 tensors at the release's 8 layers). ``pe_noise`` != 0: a PE that is not the sinusoid,
    which only an importer that reads the checkpoint's table reproduces."""
    rand, state = _Random(seed, std), dict[str, torch.Tensor]()
    _shared(state, s, rand, pe_noise, head_out=s.nb_code)
    state["token_emb.weight"] = rand(s.nb_code + 2, s.code_dim, scale=1.0)
    return state


def residual_state(s: MomaskSizes, seed: int = 2, std: float = 0.05, pe_noise: float = 0.0) -> dict[str, torch.Tensor]:
    """'res_transformer' with share_weight (112 tensors at the release's 8 layers). Its tables are both embeddings
    and classifiers: at 3 / sqrt(code_dim) the logits are a few units, at any width."""
    rand, state = _Random(seed, std), dict[str, torch.Tensor]()
    vocab, table = s.nb_code + 1, 3 / math.sqrt(s.code_dim)
    state["embed_proj_shared_weight"] = rand(s.quantizers - 2, vocab, s.code_dim, scale=table)
    state["token_embed_weight_"] = rand(1, vocab, s.code_dim, scale=table)
    state["output_proj_weight_"] = rand(1, vocab, s.code_dim, scale=table)
    _shared(state, s, rand, pe_noise, head_out=s.code_dim)
    state["quant_emb.weight"], state["quant_emb.bias"] = rand(s.latent, s.quantizers), rand(s.latent)
    return state


def estimator_state(s: MomaskSizes, seed: int = 3) -> dict[str, torch.Tensor]:
    """'estimator': output.{0,4,8,11} linears, output.{1,5,9} LayerNorms."""
    rand, state = _Random(seed, 0.1), {}
    sizes = [s.text_dim, s.length_hidden, s.length_hidden // 2, s.length_hidden // 4]
    for index, (size_in, size_out) in zip((0, 4, 8), itertools.pairwise(sizes)):
        state[f"output.{index}.weight"], state[f"output.{index}.bias"] = rand(size_out, size_in), rand(size_out)
        state[f"output.{index + 1}.weight"] = 1 + rand(size_out)
        state[f"output.{index + 1}.bias"] = rand(size_out)
    state["output.11.weight"], state["output.11.bias"] = rand(s.length_classes, sizes[-1]), rand(s.length_classes)
    return state


def _training_entries(state: dict[str, torch.Tensor], name: str, milestone: int) -> dict:
    """'opt_<name>' and 'scheduler' as torch writes them (AdamW after one step; MultiStepLR with a Counter)."""
    parameters = [torch.nn.Parameter(torch.zeros_like(v)) for k, v in state.items() if not k.endswith(".pe")]
    optimizer = torch.optim.AdamW(parameters, lr=2e-4, betas=(0.9, 0.99), weight_decay=1e-5)
    scheduler = torch.optim.lr_scheduler.MultiStepLR(optimizer, milestones=[milestone], gamma=0.1)
    for parameter in parameters:
        parameter.grad = torch.ones_like(parameter)
    optimizer.step()
    scheduler.step()
    return {f"opt_{name}": optimizer.state_dict(), "scheduler": scheduler.state_dict()}


@dataclass
class ReleaseStates:
    vq: dict[str, torch.Tensor]
    masked: dict[str, torch.Tensor]
    residual: dict[str, torch.Tensor]
    estimator: dict[str, torch.Tensor]
    mean: np.ndarray
    std: np.ndarray


def release_states(s: MomaskSizes, seed: int = 0, pe_noise: float = 0.0, std: float = 0.05) -> ReleaseStates:
    rng = np.random.default_rng(seed)
    return ReleaseStates(vq_state(s, seed), masked_state(s, seed + 1, std, pe_noise),
                         residual_state(s, seed + 2, std, pe_noise), estimator_state(s, seed + 3),
                         rng.normal(size=s.feat_dim).astype(np.float32),
                         rng.uniform(0.1, 1.0, size=s.feat_dim).astype(np.float32))


def write_release(root: Path, states: ReleaseStates, *, suffix: str = "", optimizer: bool = True,
                  length: bool = True) -> dict[str, Path]:
    """``root`` = MoMask's ``checkpoints/t2m`` (``suffix="_k"``: KIT's names). Returns the files by role."""
    files = {"vq": root / (VQ_DIR + suffix) / "model" / "net_best_fid.tar",
             "mean": root / (VQ_DIR + suffix) / "meta" / "mean.npy",
             "std": root / (VQ_DIR + suffix) / "meta" / "std.npy",
             "masked": root / (MASKED_DIR + suffix) / "model" / "latest.tar",
             "residual": root / (RESIDUAL_DIR + suffix) / "model" / "net_best_fid.tar",
             "length": root / LENGTH_DIR / "model" / "finest.tar"}
    for path in files.values():
        path.parent.mkdir(parents=True, exist_ok=True)
    torch.save({"vq_model": states.vq, "ep": 49}, files["vq"])
    np.save(files["mean"], states.mean)
    np.save(files["std"], states.std)
    masked = {"t2m_transformer": states.masked}
    if optimizer:
        masked |= _training_entries(states.masked, "t2m_transformer", 50000)
    torch.save({**masked, "ep": 499, "total_it": 123456}, files["masked"])
    torch.save({"res_transformer": states.residual, "ep": 217}, files["residual"])
    if length:
        torch.save({"estimator": states.estimator, "epoch": 30, "niter": 9000}, files["length"])
    else:
        del files["length"]
    for folder in (VQ_DIR, MASKED_DIR, RESIDUAL_DIR):
        (root / (folder + suffix) / "opt.txt").write_text("------------ Options -------------\n", encoding="utf-8")
    return files


def small(**changes: int) -> MomaskSizes:
    return replace(SMALL, **changes)
