"""Random-weight MDM / DiP releases in EXACTLY the official layout (../shared/docs/diffusion-models.md §4): a folder
with ``args.json`` (``json.dump(vars(args), indent=4, sort_keys=True)`` of the trainer's arguments) and
``model<9-digit step>.pt`` (``torch.save`` of a plain state dict, or ``{'model': sd, 'model_avg': sd_ema}`` when
trained with ``--use_ema``), the state-dict keys and shapes written out from the facts' list (§4.3), not from our
module: both positional tables saved (one shared [5000, 1, E] tensor), no text-encoder keys unless asked.

Sizes are parameters: the released ones (``RELEASE_SIZES``) in the slow tests, small ones (``SMALL_SIZES``)
elsewhere; ff 1024 and 4 heads are the official code's constants, so even the small releases keep them.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from t2m.families.diffusion.distilbert_release import write_distilbert_folder
from t2m.model.networks.positions import sinusoid_table
from t2m.testing.clip_release import openai_clip_state, save_torchscript_archive


@dataclass(frozen=True)
class ReleaseSizes:
    latent: int = 512
    layers: int = 8
    ff: int = 1024
    features: int = 263
    pe_rows: int = 5000


RELEASE_SIZES = ReleaseSizes()
SMALL_SIZES = ReleaseSizes(latent=32, layers=2)

# args.json of the official trainer: the 2022 paper model's keys (no mask_frames / use_ema / text_encoder_type:
# they entered the parser in 2025), and the 2025 parser's extra keys for the newer releases
PAPER_ARGS = {
    "arch": "trans_enc", "batch_size": 64, "cond_mask_prob": 0.1, "cuda": True, "data_dir": "", "dataset": "humanml",
    "device": 0, "diffusion_steps": 1000, "emb_trans_dec": False, "eval_batch_size": 32,
    "eval_during_training": False, "eval_num_samples": 1000, "eval_rep_times": 5, "eval_split": "test",
    "lambda_fc": 0.0, "lambda_rcxyz": 0.0, "lambda_vel": 0.0, "latent_dim": 512, "layers": 8, "log_interval": 1000,
    "lr": 0.0001, "lr_anneal_steps": 0, "noise_schedule": "cosine", "num_frames": 60, "num_steps": 600000,
    "overwrite": False, "resume_checkpoint": "", "save_dir": "save/humanml_trans_enc_512", "save_interval": 50000,
    "seed": 10, "sigma_small": True, "train_platform_type": "NoPlatform", "unconstrained": False,
    "weight_decay": 0.0,
}
NEW_KEYS = {"text_encoder_type": "clip", "mask_frames": False, "use_ema": False, "context_len": 0, "pred_len": 0,
            "pos_embed_max_len": 5000, "lambda_target_loc": 0.0, "multi_target_cond": False,
            "multi_encoder_type": "single", "target_enc_layers": 1, "gen_during_training": False,
            "avg_model_beta": 0.9999, "adam_beta2": 0.999, "use_recon_guidance": False, "autoregressive": False}
FIFTY_ARGS = PAPER_ARGS | {"diffusion_steps": 50, "save_dir": "save/humanml_trans_enc_512_50steps"}
BERT_ARGS = PAPER_ARGS | NEW_KEYS | {"arch": "trans_dec", "text_encoder_type": "bert", "diffusion_steps": 50,
                                     "mask_frames": True, "use_ema": True,
                                     "save_dir": "save/humanml_trans_dec_512_bert-50steps"}
DIP_ARGS = BERT_ARGS | {"diffusion_steps": 10, "context_len": 20, "pred_len": 40, "autoregressive": True,
                        "save_dir": "save/DiP_no-target_10steps_context20_predict40"}


def release_state(decoder: bool, text_dim: int, sizes: ReleaseSizes = SMALL_SIZES, seed: int = 0,
                  std: float | None = None) -> dict[str, torch.Tensor]:
    """The state dict of §4.3 with random values (LayerNorm weights near 1), both pe keys one shared table."""
    g = torch.Generator().manual_seed(seed)
    e, f, ff = sizes.latent, sizes.features, sizes.ff
    scale = std if std is not None else 1 / math.sqrt(e)

    def rand(*shape: int, s: float | None = None) -> torch.Tensor:
        return torch.randn(*shape, generator=g) * (scale if s is None else s)

    pe = sinusoid_table(sizes.pe_rows, e)
    state = {"input_process.poseEmbedding.weight": rand(e, f, s=1 / math.sqrt(f)),
             "input_process.poseEmbedding.bias": rand(e, s=0.02), "sequence_pos_encoder.pe": pe}
    stack = "seqTransDecoder" if decoder else "seqTransEncoder"
    for i in range(sizes.layers):
        p = f"{stack}.layers.{i}."
        for attention in ("self_attn", "multihead_attn") if decoder else ("self_attn",):
            state |= {p + f"{attention}.in_proj_weight": rand(3 * e, e), p + f"{attention}.in_proj_bias": rand(3 * e),
                      p + f"{attention}.out_proj.weight": rand(e, e), p + f"{attention}.out_proj.bias": rand(e)}
        state |= {p + "linear1.weight": rand(ff, e), p + "linear1.bias": rand(ff, s=0.02),
                  p + "linear2.weight": rand(e, ff, s=1 / math.sqrt(ff)), p + "linear2.bias": rand(e, s=0.02)}
        for norm in ("norm1", "norm2", "norm3") if decoder else ("norm1", "norm2"):
            state |= {p + f"{norm}.weight": 1 + rand(e, s=0.1), p + f"{norm}.bias": rand(e, s=0.1)}
    state |= {"embed_timestep.sequence_pos_encoder.pe": pe,
              "embed_timestep.time_embed.0.weight": rand(e, e), "embed_timestep.time_embed.0.bias": rand(e, s=0.02),
              "embed_timestep.time_embed.2.weight": rand(e, e), "embed_timestep.time_embed.2.bias": rand(e, s=0.02),
              "embed_text.weight": rand(e, text_dim, s=1 / math.sqrt(text_dim)), "embed_text.bias": rand(e, s=0.1),
              "output_process.poseFinal.weight": rand(f, e), "output_process.poseFinal.bias": rand(f, s=0.02)}
    return state


def release_args(base: dict, sizes: ReleaseSizes) -> dict:
    return base | {"latent_dim": sizes.latent, "layers": sizes.layers}


def write_release(root: Path, args: dict, state: dict[str, torch.Tensor],
                  ema: dict[str, torch.Tensor] | None = None, name: str = "model000200000.pt") -> Path:
    """The folder: args.json as the trainer writes it, the weights as it saves them (EMA: {'model', 'model_avg'}),
    and an opt file beside them (never read)."""
    root.mkdir(parents=True, exist_ok=True)
    with open(root / "args.json", "w") as handle:
        json.dump(args, handle, indent=4, sort_keys=True)
    torch.save(state if ema is None else {"model": state, "model_avg": ema}, root / name)
    torch.save({"state": {}, "param_groups": []}, root / ("opt" + name.removeprefix("model")))
    return root


# the small text encoders of the default suite: a 2-layer CLIP tower with ViT-B/32's 512-d features, a 1-layer
# DistilBERT with the released width (768: embed_text takes 768-d states)
SMALL_CLIP: dict[str, Any] = {"width": 64, "layers": 2, "embed_dim": 512}
SMALL_BERT = {"max_position_embeddings": 64, "dim": 768, "n_layers": 1, "n_heads": 12, "hidden_dim": 64}
# name -> (args.json, trans_dec); trans_dec is also the DistilBERT text encoder in these releases
RELEASES = {"paper": (PAPER_ARGS, False), "fifty": (FIFTY_ARGS, False), "bert": (BERT_ARGS, True),
            "dip": (DIP_ARGS, True)}


def small_clip_archive(folder: Path) -> Path:
    return save_torchscript_archive(openai_clip_state(**SMALL_CLIP, seed=5), folder / "ViT-B-32.pt")


def small_bert_folder(folder: Path) -> Path:
    return write_distilbert_folder(folder / "distilbert-base-uncased", SMALL_BERT)


def make_release(root: Path, name: str, sizes: ReleaseSizes = SMALL_SIZES, **args_changes
                 ) -> tuple[Path, dict[str, torch.Tensor]]:
    """A release folder and the state dict an import must read (model_avg for the EMA releases)."""
    base, decoder = RELEASES[name]
    args = release_args(base, sizes) | args_changes
    text_dim = 768 if args.get("text_encoder_type") == "bert" else 512
    state = release_state(decoder, text_dim, sizes, seed=1)
    ema = release_state(decoder, text_dim, sizes, seed=2) if args.get("use_ema") else None
    write_release(root, args, state, ema)
    return root, (ema if ema is not None else state)


def write_statistics(folder: Path, dim: int = 263, seed: int = 0) -> Path:
    """HumanML3D's generation statistics as its folder holds them (Mean.npy, Std.npy), random: what `--humanml3d DIR`
    reads. For a benchmark, where the values do not matter; a test that checks numbers uses the real sample's."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    np.save(folder / "Mean.npy", rng.normal(size=dim).astype(np.float32))
    np.save(folder / "Std.npy", rng.uniform(0.1, 1.0, size=dim).astype(np.float32))
    return folder
