"""Import MoGenTS's released checkpoints (``t2m import mogents``) as a bundle of the masked family, exactly.

Facts used: ../shared/docs/masked-models.md §2 (both branches, the fused VQ, the 2D transformers, keys and shapes,
inference) and §3 (hazards). The release is two token generators on the same rows, decoded together:

- the 2D "ts" branch: ``MaskedTransformer`` / ``ResidualTransformer`` with 2D positions, 6 columns and the three
  stacks (the bundle's primary generator: masked.onnx, residual.onnx);
- the 1D "aux" branch: MoMask's models with the checkpoint's LEARNED ``position_enc.pe`` (the manifest's
  ``masked.branches`` entry "aux": masked_aux.onnx, residual_aux.onnx);
- ``FusedVQVAE``: one decoder graph over the joined map [B, T, 6 + 1, 6].

The release's quirks that change its outputs are reproduced (the model card says which and why):
``temporal_mask_cond`` (the mask model's temporal stack cannot see the text row: the in-place mask write),
``spatial_rows_from_zero`` and ``spatial_scramble`` (the residual model's spatial stack: positions from row 0 and
its output laid out without the transpose, as one motion per call - the demo's B = 1), ``residual_mask_class``
(258 classes; a drawn mask id clips the motion's map to [0, 255]), a mask-stage temperature fixed at 1 (MoGenTS's
sampler ignores it). Sizes come from tensor shapes; heads (6), 49 rows and the dilation growth (3) are the
release's values, as for MoMask.
"""
from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch

from t2m.export.importers.kit import import_quantized, load_checked, read_stat, require_tensor, shape_text
from t2m.families.gpt.import_t2m_gpt import RELEASE_DILATION_GROWTH
from t2m.families.masked.export import MaskedDecoding, MaskedExportChecks, TokenBranch, export_masked_bundle
from t2m.families.masked.import_momask import (
    RELEASE_HEADS,
    RELEASE_RESIDUAL_GUIDANCE,
    RELEASE_STEPS,
    encoder_sizes,
    load_length,
    read_positions,
    read_release,
    release_top_k,
    token_config,
)
from t2m.families.masked.masked_transformer import MaskedTransformer
from t2m.families.masked.mogents_card import release_notes
from t2m.families.masked.mogents_files import ImportedMogents, locate_release, read_states
from t2m.families.masked.momask_files import MomaskFiles
from t2m.families.masked.residual_transformer import ResidualTransformer
from t2m.model.networks.fused_vqvae import FusedVQConfig, FusedVQVAE

__all__ = ["ImportedMogents", "import_mogents", "load_mogents", "release_decoding"]

RELEASE = "MoGenTS"
RELEASE_GUIDANCE = 4.0       # README's evaluation commands, HumanML3D and KIT-ML: --cond_scale 4
CLIP_REQUIRED = ("a MoGenTS import needs CLIP ViT-B/32 weights for its text encoder: pass --clip ViT-B-32.pt "
                 "(OpenAI's file, as clip.load downloads it)")


def release_decoding(vq: FusedVQVAE) -> tuple[MaskedDecoding, tuple[int, int]]:
    """(the ts branch's settings, the aux branch's (top-k, residual top-k)): 10 steps, guidance 4 and 5, top-k
    ceil((1 - 0.9) V) of each stage's classes (26 of 256 and of 258; 52 of 512 and of 513), temperature 1 in both
    stages (the mask stage's sampler ignores any other)."""
    c = vq.config
    decoding = MaskedDecoding(steps=RELEASE_STEPS, guidance=RELEASE_GUIDANCE,
                              residual_guidance=RELEASE_RESIDUAL_GUIDANCE, top_k=release_top_k(c.nb_code),
                              residual_top_k=release_top_k(c.nb_code + 2), residual_temperature=1.0,
                              temperature=1.0)
    return decoding, (release_top_k(c.nb_code1d), release_top_k(c.nb_code1d + 1))


# ------------------------------------------------------------------------------------------------ tensor reading

def _layers(state: Mapping[str, torch.Tensor], prefix: str) -> int:
    count = 0
    while f"{prefix}.{count}.codebook" in state:
        count += 1
    return count


def _fused_vq(path: Path, allow_pickle: bool) -> tuple[FusedVQVAE, str]:
    ((key, state),) = read_states(path, "vq", allow_pickle)
    where = f"{path} ['{key}']"
    first = require_tensor(state, "encoder1d.model.0.weight", where, "[width, features, 3]", 3)
    book2d = require_tensor(state, "quantizer2d.layers.0.codebook", where, "[codes, code_dim] (the 2D codebook)", 2)
    book1d = require_tensor(state, "quantizer1d.layers.0.codebook", where, "[codes, code_dim] (the 1D codebook)", 2)
    depth = 0
    while f"encoder1d.model.2.1.model.{depth}.conv1.weight" in state:
        depth += 1
    layers = _layers(state, "quantizer2d.layers")
    if layers < 2 or _layers(state, "quantizer1d.layers") != layers:
        raise ValueError(f"{where}: {layers} 2D and {_layers(state, 'quantizer1d.layers')} 1D quantiser layers; "
                         "MoGenTS's VQ has the same number (several) in both")
    config = FusedVQConfig(feat_dim=int(first.shape[1]), width=int(first.shape[0]), code_dim=int(book2d.shape[1]),
                           nb_code=int(book2d.shape[0]), code_dim1d=int(book1d.shape[1]),
                           nb_code1d=int(book1d.shape[0]), depth=max(depth, 1),
                           dilation_growth=RELEASE_DILATION_GROWTH, residual_layers=layers)
    return load_checked(FusedVQVAE(config), state, where, RELEASE), key


def _positions_2d(state: dict[str, torch.Tensor], where: str, rows: int, columns: int, latent: int) -> None:
    """The checkpoint's 2D table [200, 50, latent], cut to the rows and columns a map can have."""
    expected = f"[>= {rows}, >= {columns}, {latent}]"
    pe = require_tensor(state, "position2d_enc.pe", where, expected, 3)
    if pe.shape[0] < rows or pe.shape[1] < columns or pe.shape[2] != latent:
        raise ValueError(f"{where}: tensor 'position2d_enc.pe' has shape {shape_text(pe.shape)}, expected {expected}")
    state["position2d_enc.pe"] = pe[:rows, :columns].clone()


def _ts_models(path_m: Path, path_r: Path, vq: FusedVQVAE, heads: int, states: dict[str, Any]
               ) -> tuple[MaskedTransformer, ResidualTransformer]:
    """The 2D models, with the release's layout and quirks."""
    c = vq.config
    models: list[Any] = []
    for role, path, model_type, quirks in (
            ("masked", path_m, MaskedTransformer, {"temporal_mask_cond": True}),
            ("residual", path_r, ResidualTransformer, {"spatial_rows_from_zero": True, "spatial_scramble": True,
                                                       "residual_mask_class": True})):
        key, state = states[role][0]
        where = f"{path} ['{key}']"
        config = token_config(encoder_sizes(state, where, heads), c.nb_code, c.residual_layers, c.code_dim,
                              columns=c.columns, positional="2d", spatial_attention=True, temporal_attention=True,
                              **quirks)
        prefix = 1 if model_type is MaskedTransformer else 2
        _positions_2d(state, where, config.max_tokens + prefix, config.columns, config.latent)
        models.append(load_checked(model_type(config), state, where, RELEASE))
    return models[0], models[1]


def _aux_models(path_m: Path, path_r: Path, vq: FusedVQVAE, heads: int, states: dict[str, Any]
                ) -> tuple[MaskedTransformer, ResidualTransformer]:
    """The 1D models: MoMask's, with the checkpoint's learned positional table."""
    c = vq.config
    models: list[Any] = []
    for role, path, model_type in (("masked", path_m, MaskedTransformer), ("residual", path_r, ResidualTransformer)):
        key, state = states[role][1]
        where = f"{path} ['{key}']"
        config = token_config(encoder_sizes(state, where, heads), c.nb_code1d, c.residual_layers, c.code_dim1d)
        read_positions(state, where, config.latent, config.max_tokens)
        models.append(load_checked(model_type(config), state, where, RELEASE))
    return models[0], models[1]


def load_mogents(files: MomaskFiles, heads: int = RELEASE_HEADS, allow_pickle: bool = False) -> ImportedMogents:
    """Rebuild the release's networks as our modules (every tensor checked, strict loads)."""
    vq, vq_key = _fused_vq(files.vq, allow_pickle)
    mean, std = (read_stat(path, vq.config.feat_dim) for path in (files.mean, files.std))
    states = {"masked": read_states(files.masked, "masked", allow_pickle),
              "residual": read_states(files.residual, "residual", allow_pickle)}
    masked, residual = _ts_models(files.masked, files.residual, vq, heads, states)
    masked_aux, residual_aux = _aux_models(files.masked, files.residual, vq, heads, states)
    keys = {f"{role}{suffix}": states[role][index][0] for role in states
            for index, suffix in ((0, ""), (1, "_aux"))}
    keys["vq"] = vq_key
    length = None
    if files.length is not None:
        length, keys["length"] = load_length(files.length, masked.config.text_dim, allow_pickle)
    return ImportedMogents(files, vq, masked, residual, masked_aux, residual_aux, length, mean, std, keys)


def import_mogents(
    logs_dir: str | Path | None,
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
    """The whole import: the release's files -> our modules -> a verified masked bundle with two generators (their
    token graphs quantised with ``quantize``: int8, int4 or fp16; kit.import_quantized)."""
    return import_quantized(out_dir, quantize, lambda out: _import_mogents(
        logs_dir, out, clip_weights=clip_weights, files=files, heads=heads, name=name, version=version,
        check_parity=check_parity, allow_pickle=allow_pickle))


def _import_mogents(logs_dir: str | Path | None, out_dir: Path, *, clip_weights: str | Path | None,
                    files: Mapping[str, str | Path | None] | None, heads: int, name: str | None, version: str,
                    check_parity: bool, allow_pickle: bool) -> tuple[dict, MaskedExportChecks]:
    located = locate_release(logs_dir, files or {})
    text_source, models = read_release(clip_weights, CLIP_REQUIRED, located,
                                       lambda: load_mogents(located, heads, allow_pickle))
    decoding, (aux_top_k, aux_residual_top_k) = release_decoding(models.vq)
    aux = TokenBranch("aux", models.masked_aux, models.residual_aux, aux_top_k, aux_residual_top_k)
    notes, training_data, license = release_notes(models, decoding, heads)
    default_name = "mogents-" + ("kit" if located.dataset == "KIT-ML" else "humanml3d")
    return export_masked_bundle(
        out_dir, vq=models.vq, masked=models.masked, residual=models.residual, length=models.length,
        mean=models.mean, std=models.std, text_source=text_source, name=name or default_name, version=version,
        training_data=training_data, license=license, decoding=decoding, unconditional_branch=True, notes=notes,
        check_parity=check_parity, branches=[aux])

