"""Import MoMask's released checkpoints (``t2m import momask``) as a bundle of the masked family, exactly.

Facts used: ../shared/docs/masked-models.md §1 (modules, key layout, inference recipe) and §3 (hazards). Our
masked-family modules carry MoMask's key names by configuration (1D positions, one column, one stack, share-weight
residual tables), so every tensor loads strictly once the sizes are known. Sizes come from tensor shapes; what
shapes cannot tell is the release's value:

- attention heads: 6 (``heads=`` overrides it; a wrong count loads but computes another model);
- the longest motion: 49 token rows (196 frames; MoMask's ``max_motion_length``), which is also the length
  estimator's 50 classes - 1; the checkpoint's positional table (``position_enc.pe``, 5000 rows) is read, not
  regenerated, and its first 49 rows are kept;
- the dilation growth of the VQ's residual blocks: 3 (dilations 9, 3, 1).

The decoding settings are the release's evaluation settings (:func:`release_decoding`); the loop
(t2m.families.masked.loop) computes MoMask's ``generate`` with them, see t2m/families/masked/README.md "Importing
MoMask".
"""
from __future__ import annotations

import logging
import math
import re
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, TypeVar

import torch

from t2m.export.importers.kit import import_quantized, load_checked, read_stat, require_tensor, shape_text
from t2m.export.kit.text_sources import TextSource, clip_text_source
from t2m.families.gpt.import_t2m_gpt import infer_vq_config
from t2m.families.masked.export import MaskedDecoding, MaskedExportChecks, export_masked_bundle
from t2m.families.masked.length_estimator import LengthEstimator, LengthEstimatorConfig
from t2m.families.masked.masked_transformer import MaskedTransformer
from t2m.families.masked.momask_card import release_notes
from t2m.families.masked.momask_files import (
    ImportedMomask,
    MomaskFiles,
    kit_fps_note,
    locate_release,
    read_state,
)
from t2m.families.masked.residual_transformer import ResidualTransformer
from t2m.model.networks.token_transformer import TokenTransformerConfig
from t2m.model.networks.vqvae import MotionVQVAE

log = logging.getLogger(__name__)

__all__ = ["ImportedMomask", "import_momask", "load_momask", "release_decoding", "release_top_k"]

RELEASE_HEADS = 6
RELEASE_MAX_TOKENS = 49
RELEASE_DROPOUT = 0.2
RELEASE_STEPS = 10
RELEASE_GUIDANCE = {"HumanML3D": 4.0, "KIT-ML": 2.0}   # README's evaluation commands (--cond_scale)
RELEASE_RESIDUAL_GUIDANCE = 5.0                        # gen_t2m.py / evaluation: cond_scale=5, temperature=1
KEEP_RATIO = 0.9                                       # --topkr: top-k keeps ceil((1 - 0.9) V) classes
CLIP_REQUIRED = ("a MoMask import needs CLIP ViT-B/32 weights for its text encoder: pass --clip ViT-B-32.pt "
                 "(OpenAI's file, as clip.load downloads it)")


def release_top_k(vocabulary: int) -> int:
    """MoMask's top-k for ``vocabulary`` classes: ceil((1 - 0.9) V), computed in floats as MoMask does
    ((1 - 0.9) is a little below 0.1, so V = 30 gives 3 where ceil(0.1 V) would give 4); 512 -> 52, 513 -> 52."""
    return math.ceil((1 - KEEP_RATIO) * vocabulary)


def release_decoding(dataset: str, codebook_size: int) -> MaskedDecoding:
    """The release's evaluation settings: 10 steps, guidance 4 (KIT-ML: 2) and 5, top-k 10% of each stage's
    classes (K codes; K + 1 with the residual stage's pad), the residual stage at temperature 1."""
    return MaskedDecoding(steps=RELEASE_STEPS, guidance=RELEASE_GUIDANCE.get(dataset, 4.0),
                          residual_guidance=RELEASE_RESIDUAL_GUIDANCE, top_k=release_top_k(codebook_size),
                          residual_top_k=release_top_k(codebook_size + 1), residual_temperature=1.0)


# --------------------------------------------------------------------------------------------- tensor checks





def _count(state: Mapping[str, torch.Tensor], pattern: str) -> int:
    regex = re.compile(pattern)
    return len({m.group(1) for k in state if (m := regex.fullmatch(k))})






# ------------------------------------------------------------------------------------------------ the four models

def _vq(path: Path, allow_pickle: bool) -> tuple[MotionVQVAE, str]:
    key, state = read_state(path, "vq", allow_pickle)
    where = f"{path} ['{key}']"
    require_tensor(state, "encoder.model.0.weight", where, "[width, features, 3]", 3)
    if "quantizer.layers.0.codebook" not in state:
        raise ValueError(f"{where}: missing tensor 'quantizer.layers.0.codebook' (MoMask's RVQ-VAE has one codebook "
                         "per quantiser layer)")
    config = infer_vq_config(state, where)
    if config.residual_layers < 2:
        raise ValueError(f"{where}: {config.residual_layers} quantiser layer; MoMask's RVQ-VAE has several")
    return load_checked(MotionVQVAE(config), state, where, "MoMask"), key


def encoder_sizes(state: Mapping[str, torch.Tensor], where: str, heads: int) -> dict[str, int]:
    cond = require_tensor(state, "cond_emb.weight", where, "[latent, text_dim]", 2)
    layers = _count(state, r"seqTransEncoder\.layers\.(\d+)\.linear1\.weight")
    if layers == 0:
        raise ValueError(f"{where}: missing tensor 'seqTransEncoder.layers.0.linear1.weight' [ff, latent]")
    ff = require_tensor(state, "seqTransEncoder.layers.0.linear1.weight", where, "[ff, latent]", 2)
    latent = int(cond.shape[0])
    if heads < 1 or latent % heads:
        raise ValueError(f"--heads {heads} does not divide the transformer width {latent}")
    return {"latent": latent, "text_dim": int(cond.shape[1]), "n_layer": layers, "ff_size": int(ff.shape[0]),
            "n_head": heads}


def read_positions(state: dict[str, torch.Tensor], where: str, latent: int, rows: int) -> None:
    """The checkpoint's own positional table, cut to the rows a motion can have (the rest is never read)."""
    pe = require_tensor(state, "position_enc.pe", where, f"[>= {rows}, 1, {latent}]", 3)
    if pe.shape[0] < rows or tuple(pe.shape[1:]) != (1, latent):
        raise ValueError(f"{where}: tensor 'position_enc.pe' has shape {shape_text(pe.shape)}, expected "
                         f"[>= {rows}, 1, {latent}]")
    state["position_enc.pe"] = pe[:rows].clone()


def token_config(sizes: dict[str, int], codebook_size: int, residual_layers: int, code_dim: int,
                 **layout: Any) -> TokenTransformerConfig:
    """A released transformer's config: sizes read from its tensors, the release's values, MoMask's 1D layout
    unless ``layout`` says otherwise (MoGenTS's 2D models)."""
    return TokenTransformerConfig(**{
        "codebook_size": codebook_size, "columns": 1, "residual_layers": residual_layers,
        "max_tokens": RELEASE_MAX_TOKENS, "latent": sizes["latent"], "n_head": sizes["n_head"],
        "n_layer": sizes["n_layer"], "ff_size": sizes["ff_size"], "dropout": RELEASE_DROPOUT,
        "text_dim": sizes["text_dim"], "code_dim": code_dim, "positional": "1d", "spatial_attention": False,
        "temporal_attention": False, "share_weight": True, **layout})


def _token_config(vq: MotionVQVAE, sizes: dict[str, int]) -> TokenTransformerConfig:
    return token_config(sizes, vq.config.nb_code, vq.config.residual_layers, vq.config.code_dim)


def _masked(path: Path, vq: MotionVQVAE, heads: int, allow_pickle: bool) -> tuple[MaskedTransformer, str]:
    key, state = read_state(path, "masked", allow_pickle)
    where = f"{path} ['{key}']"
    config = _token_config(vq, encoder_sizes(state, where, heads))
    read_positions(state, where, config.latent, config.max_tokens)
    return load_checked(MaskedTransformer(config), state, where, "MoMask"), key


def _residual(path: Path, vq: MotionVQVAE, heads: int, allow_pickle: bool) -> tuple[ResidualTransformer, str]:
    key, state = read_state(path, "residual", allow_pickle)
    where = f"{path} ['{key}']"
    if "token_embed_weight_" not in state:
        raise ValueError(f"{where}: missing tensor 'token_embed_weight_' [1, {vq.config.nb_code + 1}, "
                         f"{vq.config.code_dim}] (the release's residual transformer shares its tables)")
    config = _token_config(vq, encoder_sizes(state, where, heads))
    read_positions(state, where, config.latent, config.max_tokens)
    return load_checked(ResidualTransformer(config), state, where, "MoMask"), key


def load_length(path: Path, text_dim: int, allow_pickle: bool) -> tuple[LengthEstimator, str]:
    """The length estimator (MoMask's layout, read by both importers)."""
    key, state = read_state(path, "length", allow_pickle)
    where = f"{path} ['{key}']"
    first = require_tensor(state, "output.0.weight", where, f"[hidden, {text_dim}]", 2)
    hidden = int(first.shape[0])
    if hidden < 4:
        raise ValueError(f"{where}: tensor 'output.0.weight' has shape {shape_text(first.shape)}, expected "
                         f"[hidden >= 4, {text_dim}]")
    config = LengthEstimatorConfig(text_dim=text_dim, hidden=hidden, max_tokens=RELEASE_MAX_TOKENS,
                                   dropout=RELEASE_DROPOUT)
    return load_checked(LengthEstimator(config), state, where, "MoMask"), key


def load_momask(files: MomaskFiles, heads: int = RELEASE_HEADS, allow_pickle: bool = False) -> ImportedMomask:
    """Rebuild the release's four networks as our modules (every tensor checked, strict loads)."""
    vq, vq_key = _vq(files.vq, allow_pickle)
    mean, std = (read_stat(path, vq.config.feat_dim) for path in (files.mean, files.std))
    masked, masked_key = _masked(files.masked, vq, heads, allow_pickle)
    residual, residual_key = _residual(files.residual, vq, heads, allow_pickle)
    if residual.config.text_dim != masked.config.text_dim:
        raise ValueError(f"{files.residual}: text dim {residual.config.text_dim}, the masked transformer's "
                         f"{masked.config.text_dim}")
    keys = {"vq": vq_key, "masked": masked_key, "residual": residual_key}
    length = None
    if files.length is not None:
        length, keys["length"] = load_length(files.length, masked.config.text_dim, allow_pickle)
    return ImportedMomask(files, vq, masked, residual, length, mean, std, keys)


ModelsT = TypeVar("ModelsT")


def read_release(clip_weights: str | Path | None, clip_required: str, located: MomaskFiles,
                 load: Callable[[], ModelsT]) -> tuple[TextSource, ModelsT]:
    """What every release import does first: the CLIP file (refused before the slow checkpoint loads), the models,
    one warning line per gap of the release (no length estimator, KIT's frame rate)."""
    if clip_weights is None:
        raise ValueError(clip_required)
    text_source = clip_text_source(clip_weights)
    models = load()
    for note in (located.missing_length_note(), kit_fps_note(located.dataset)):
        if note:
            log.warning("%s", note)
    return text_source, models


def import_momask(
    checkpoints_dir: str | Path | None,
    out_dir: str | Path,
    *,
    clip_weights: str | Path | None,
    files: Mapping[str, str | Path | None] | None = None,
    heads: int = RELEASE_HEADS,
    name: str | None = None,
    version: str = "1.0.0",
    check_parity: bool = True,
    allow_pickle: bool = False,
    quantize: str | None = None,
) -> tuple[dict, MaskedExportChecks]:
    """The whole import: the release's files -> our modules -> a verified masked bundle with the release's settings
    (its token graphs quantised with ``quantize``: int8, int4 or fp16; kit.import_quantized)."""
    return import_quantized(out_dir, quantize, lambda out: _import_momask(
        checkpoints_dir, out, clip_weights=clip_weights, files=files, heads=heads, name=name, version=version,
        check_parity=check_parity, allow_pickle=allow_pickle))


def _import_momask(checkpoints_dir: str | Path | None, out_dir: Path, *, clip_weights: str | Path | None,
                   files: Mapping[str, str | Path | None] | None, heads: int, name: str | None, version: str,
                   check_parity: bool, allow_pickle: bool) -> tuple[dict, MaskedExportChecks]:
    located = locate_release(checkpoints_dir, files or {})
    text_source, models = read_release(clip_weights, CLIP_REQUIRED, located,
                                       lambda: load_momask(located, heads, allow_pickle))
    decoding = release_decoding(located.dataset, models.vq.config.nb_code)
    notes, training_data, license = release_notes(models, decoding, heads)
    default_name = "momask-" + ("kit" if located.dataset == "KIT-ML" else "humanml3d")
    return export_masked_bundle(
        out_dir, vq=models.vq, masked=models.masked, residual=models.residual, length=models.length,
        mean=models.mean, std=models.std, text_source=text_source, name=name or default_name, version=version,
        training_data=training_data, license=license, decoding=decoding, unconditional_branch=True, notes=notes,
        check_parity=check_parity)
