"""Random-weight checkpoints in EXACTLY the layout of MoGenTS's release (../shared/docs/masked-models.md §2.7):
``logs/humanml3d/pretrain_{vq,mtrans,rtrans}`` and ``checkpoints/humanml3d/length_estimator``, the top-level keys
of the best-FID files (or of latest.tar, with optimiser and scheduler entries), state-dict key names and shapes.
Built from the facts' table, not from our modules, so the importer's strict loads test the layout. The aux models
and the 1D VQ keys are MoMask's (momask_release.py) under MoGenTS's names.

Sizes are parameters: the release's (``RELEASE``) in the slow test, small ones in the default suite.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from t2m.families.masked.momask_release import (
    MomaskSizes,
    _encoder_layers,
    _Random,
    _training_entries,
    estimator_state,
    masked_state,
    residual_state,
    vq_state,
)

VQ_DIR, MASKED_DIR, RESIDUAL_DIR = "pretrain_vq", "pretrain_mtrans", "pretrain_rtrans"


@dataclass(frozen=True)
class MogentsSizes:
    """Every size of the release's networks (the release: ``RELEASE``)."""

    feat_dim: int = 263
    width: int = 512
    code_dim2d: int = 1024
    nb_code2d: int = 256
    code_dim1d: int = 512
    nb_code1d: int = 512
    quantizers: int = 6
    latent: int = 384
    heads: int = 6
    layers: int = 8
    ff: int = 1024
    text_dim: int = 512
    pe_rows: int = 5000
    pe2d: tuple[int, int] = (200, 50)
    length_hidden: int = 512

    def aux(self) -> MomaskSizes:
        """The 1D branch's sizes in MoMask's terms."""
        return MomaskSizes(feat_dim=self.feat_dim, width=self.width, code_dim=self.code_dim1d, nb_code=self.nb_code1d,
                           quantizers=self.quantizers, latent=self.latent, heads=self.heads, layers=self.layers,
                           ff=self.ff, text_dim=self.text_dim, pe_rows=self.pe_rows, length_hidden=self.length_hidden)


RELEASE = MogentsSizes()
SMALL = MogentsSizes(width=16, code_dim2d=16, nb_code2d=24, code_dim1d=16, nb_code1d=32, latent=48, layers=1, ff=64,
                     pe_rows=300, pe2d=(60, 8), length_hidden=32)


def _conv2d(state: dict, key: str, out_ch: int, in_ch: int, kernel: int, rand: _Random) -> None:
    state[f"{key}.weight"] = rand(out_ch, in_ch, kernel, kernel, scale=1 / math.sqrt(in_ch * kernel * kernel))
    state[f"{key}.bias"] = rand(out_ch, scale=0.01)


def vq_state_mogents(s: MogentsSizes, seed: int = 0) -> dict[str, torch.Tensor]:
    """'vq_model': encoder1d / decoder1d / quantizer1d (MoMask's), encoder2d / linear_merge / decoder2d /
    linear_out / quantizer2d (148 tensors)."""
    names = {"encoder.": "encoder1d.", "decoder.": "decoder1d.", "quantizer.": "quantizer1d."}
    state = {}
    for key, value in vq_state(s.aux(), seed).items():
        prefix = next(p for p in names if key.startswith(p))
        state[names[prefix] + key[len(prefix):]] = value
    rand, w, d = _Random(seed + 100, 1.0), s.width, s.code_dim2d
    _conv2d(state, "encoder2d.model.0", w, 12, 3, rand)
    for i in (2, 3):
        _conv2d(state, f"encoder2d.model.{i}.0", w, w, 4, rand)
        for j in range(3):
            _conv2d(state, f"encoder2d.model.{i}.1.model.{j}.conv1", w, w, 3, rand)
            _conv2d(state, f"encoder2d.model.{i}.1.model.{j}.conv2", w, w, 1, rand)
    _conv2d(state, "encoder2d.model.4", d, w, 3, rand)
    state["linear_merge.weight"] = rand(6 * d, 6 * d, scale=1 / math.sqrt(6 * d))
    state["linear_merge.bias"] = rand(6 * d, scale=0.01)
    _conv2d(state, "decoder2d.model.0", w, d, 3, rand)
    for i in (2, 3):
        for j in range(3):
            _conv2d(state, f"decoder2d.model.{i}.0.model.{j}.conv1", w, w, 3, rand)
            _conv2d(state, f"decoder2d.model.{i}.0.model.{j}.conv2", w, w, 1, rand)
        _conv2d(state, f"decoder2d.model.{i}.2", w, w, 3, rand)
    _conv2d(state, "decoder2d.model.4", w, w, 3, rand)
    _conv2d(state, "decoder2d.model.6", 12, w, 3, rand)
    state["linear_out.weight"] = rand(s.feat_dim, 2 * s.feat_dim, scale=1 / math.sqrt(2 * s.feat_dim))
    state["linear_out.bias"] = rand(s.feat_dim, scale=0.01)
    for q in range(s.quantizers):
        state[f"quantizer2d.layers.{q}.codebook"] = rand(s.nb_code2d, d)
    return state


def sinusoid_pe_2d(rows: int, columns: int, dim: int) -> torch.Tensor:
    """[rows, columns, dim]: channels [0:dim/2] sin/cos of the column, [dim/2:] of the row, 10000^(-2k/(dim/2))."""
    half = dim // 2
    frequency = torch.exp(torch.arange(0, half, 2, dtype=torch.float32) * (-math.log(10000.0) / half))
    column = torch.arange(columns, dtype=torch.float32)[:, None] * frequency          # [columns, half/2]
    row = torch.arange(rows, dtype=torch.float32)[:, None] * frequency
    pe = torch.zeros(rows, columns, dim)
    pe[:, :, 0:half:2], pe[:, :, 1:half:2] = torch.sin(column)[None], torch.cos(column)[None]
    pe[:, :, half::2], pe[:, :, half + 1::2] = torch.sin(row)[:, None], torch.cos(row)[:, None]
    return pe


def _ts_shared(state: dict, s: MogentsSizes, rand: _Random, pe_noise: float, head_out: int) -> None:
    """Keys both 2D transformers have: input_process, position2d_enc.pe, three stacks, cond_emb, output_process."""
    aux, dim = s.aux(), s.latent
    state["input_process.poseEmbedding.weight"] = rand(dim, s.code_dim2d)
    state["input_process.poseEmbedding.bias"] = rand(dim)
    state["position2d_enc.pe"] = sinusoid_pe_2d(*s.pe2d, dim) + rand(*s.pe2d, dim, scale=pe_noise)
    for stack in ("seqTransEncoder", "seqTransEncoder2", "seqTransEncoder3"):
        layers: dict[str, torch.Tensor] = {}
        _encoder_layers(layers, aux, rand)
        state |= {stack + key[len("seqTransEncoder"):]: value for key, value in layers.items()}
    state["cond_emb.weight"], state["cond_emb.bias"] = rand(dim, s.text_dim), rand(dim)
    state["output_process.dense.weight"], state["output_process.dense.bias"] = rand(dim, dim), rand(dim)
    state["output_process.LayerNorm.weight"] = 1 + rand(dim, scale=0.1)
    state["output_process.LayerNorm.bias"] = rand(dim)
    state["output_process.poseFinal.weight"] = rand(head_out, dim)
    state["output_process.poseFinal.bias"] = rand(head_out)


def ts_masked_state(s: MogentsSizes, seed: int = 11, std: float = 0.05, pe_noise: float = 0.0) -> dict:
    """'t2m_transformer_ts' (300 tensors at 8 layers a stack)."""
    rand, state = _Random(seed, std), dict[str, torch.Tensor]()
    _ts_shared(state, s, rand, pe_noise, head_out=s.nb_code2d)
    state["token_emb.weight"] = rand(s.nb_code2d + 2, s.code_dim2d, scale=1.0)
    return state


def ts_residual_state(s: MogentsSizes, seed: int = 12, std: float = 0.05, pe_noise: float = 0.0) -> dict:
    """'res_transformer_ts' with share_weight (304 tensors): 258-row tables (codes, mask, pad)."""
    rand, state = _Random(seed, std), dict[str, torch.Tensor]()
    vocab, table = s.nb_code2d + 2, 3 / math.sqrt(s.code_dim2d)
    state["embed_proj_shared_weight"] = rand(s.quantizers - 2, vocab, s.code_dim2d, scale=table)
    state["token_embed_weight_"] = rand(1, vocab, s.code_dim2d, scale=table)
    state["output_proj_weight_"] = rand(1, vocab, s.code_dim2d, scale=table)
    _ts_shared(state, s, rand, pe_noise, head_out=s.code_dim2d)
    state["quant_emb.weight"], state["quant_emb.bias"] = rand(s.latent, s.quantizers), rand(s.latent)
    return state


@dataclass
class MogentsStates:
    vq: dict[str, torch.Tensor]
    masked_ts: dict[str, torch.Tensor]
    residual_ts: dict[str, torch.Tensor]
    masked_aux: dict[str, torch.Tensor]
    residual_aux: dict[str, torch.Tensor]
    estimator: dict[str, torch.Tensor]
    mean: np.ndarray
    std: np.ndarray


def release_states(s: MogentsSizes, seed: int = 0, pe_noise: float = 0.1, std: float = 0.05) -> MogentsStates:
    """The aux models' positional table is trained in MoGenTS: ``pe_noise`` makes it (and the 2D tables) differ
    from any sinusoid, so only an importer that reads the checkpoints' tables reproduces them."""
    rng = np.random.default_rng(seed)
    return MogentsStates(vq_state_mogents(s, seed), ts_masked_state(s, seed + 11, std, pe_noise),
                         ts_residual_state(s, seed + 12, std, pe_noise), masked_state(s.aux(), seed + 1, std, pe_noise),
                         residual_state(s.aux(), seed + 2, std, pe_noise), estimator_state(s.aux(), seed + 3),
                         rng.normal(size=s.feat_dim).astype(np.float32),
                         rng.uniform(0.1, 1.0, size=s.feat_dim).astype(np.float32))


def write_release(root: Path, states: MogentsStates, *, dataset: str = "humanml3d", latest: bool = False,
                  length: bool = True) -> dict[str, Path]:
    """``root`` = the folder holding MoGenTS's ``logs/`` and ``checkpoints/``. Returns the files by role (and
    "logs": the LOGS_DIR argument). ``latest``: the transformer runs hold latest.tar (the other key names)."""
    logs = root / "logs" / dataset
    suffix = "_kit" if dataset == "kit" else ""
    name = "latest.tar" if latest else "net_best_fid.tar"
    files = {"vq": logs / VQ_DIR / "model" / "net_best_fid.tar", "mean": logs / VQ_DIR / "meta" / "mean.npy",
             "std": logs / VQ_DIR / "meta" / "std.npy", "masked": logs / (MASKED_DIR + suffix) / "model" / name,
             "residual": logs / (RESIDUAL_DIR + suffix) / "model" / name,
             "length": root / "checkpoints" / dataset / "length_estimator" / "model" / "finest.tar"}
    for path in files.values():
        path.parent.mkdir(parents=True, exist_ok=True)
    torch.save({"vq_model": states.vq, "ep": 49, "value": 0.01}, files["vq"])
    np.save(files["mean"], states.mean)
    np.save(files["std"], states.std)
    if latest:
        masked: dict[str, Any] = {"mask_transformer_aux": states.masked_aux, "mask_transformer_ts": states.masked_ts}
        entries = _training_entries(states.masked_aux, "mask_transformer_aux", 10**6)   # as torch writes them
        masked |= {"opt_mask_transformer_aux": entries["opt_mask_transformer_aux"],
                   "scheduler_aux": entries["scheduler"]}
        masked |= {"ep": 616, "total_it": 123456}
        residual: dict[str, Any] = {"res_transformer_aux": states.residual_aux,
                                    "res_transformer_ts": states.residual_ts, "ep": 217, "total_it": 654321}
    else:
        masked = {"t2m_transformer_aux": states.masked_aux, "t2m_transformer_ts": states.masked_ts, "ep": 616,
                  "best_value": 0.0934}
        residual = {"res_transformer_aux": states.residual_aux, "res_transformer_ts": states.residual_ts, "ep": 217,
                    "best_value": 0.0221}
    torch.save(masked, files["masked"])
    torch.save(residual, files["residual"])
    if length:
        torch.save({"estimator": states.estimator, "epoch": 30, "niter": 9000}, files["length"])
    else:
        del files["length"]
    for folder in (VQ_DIR, MASKED_DIR + suffix, RESIDUAL_DIR + suffix):
        (logs / folder / "opt.txt").write_text("------------ Options -------------\nvq_name: pretrain_vq\n",
                                               encoding="utf-8")
    return {**files, "logs": logs}


def small(**changes) -> MogentsSizes:
    return replace(SMALL, **changes)
