"""Import the released T2M-GPT checkpoints (net_last.pth + net_best_fid.pth) as a bundle.

Facts used (../shared/docs/t2m-gpt-checkpoints.md): the VQ file is {'net': state_dict} with keys
prefixed ``vqvae.``; the GPT file is {'trans': state_dict}; our MotionVQVAE and MotionGPT use the
release's module names, so both load strictly once the sizes are known. Every size is inferred
from tensor shapes, except two that shapes cannot tell:

- the number of attention heads: assumed ``embed / 64`` (the release: 1024 / 64 = 16); ``heads=``
  overrides it. A wrong head count still loads (same tensor shapes) but computes a different model.
- the dilation growth of the residual blocks (not stored in weights): the release's 3.

The release has no length conditioning and was trained without condition dropout, so the bundle
says ``unconditional_branch: false`` and ``default_guidance: 1.0``.
"""
from __future__ import annotations

import logging
import re
import shutil
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from t2m.export.importers.kit import import_quantized, load_checkpoint_entry, load_strict, strip_prefix
from t2m.export.kit.text_sources import TextSource, clip_text_source
from t2m.families.gpt.export import ExportChecks, export_bundle
from t2m.families.gpt.network import GPTConfig, MotionGPT
from t2m.model.networks.vqvae import MotionVQVAE, VQConfig

log = logging.getLogger(__name__)

HEAD_DIM_ASSUMPTION = 64
RELEASE_DILATION_GROWTH = 3
RELEASE_TRAINING_DATA = {
    "name": "HumanML3D",
    "license": "HumanML3D / AMASS terms (non-commercial research use)",
    "attribution": ("Zhang et al., T2M-GPT (CVPR 2023), released weights; trained on HumanML3D (Guo et al., "
                    "CVPR 2022), built on AMASS and HumanAct12."),
}
RELEASE_LICENSE = "as released by the T2M-GPT authors; HumanML3D / AMASS data terms apply"
CLIP_REQUIRED = (
    "a T2M-GPT import needs CLIP ViT-B/32 weights for its text encoder: pass --clip ViT-B-32.pt "
    "(OpenAI's file, as clip.load downloads it), or --text-encoder-bundle DIR to reuse the 512-d text graph of "
    "another bundle"
)


# --------------------------------------------------------------------------------------------- loading files

def load_checkpoint_dict(path: str | Path, key: str, allow_pickle: bool = False) -> dict[str, torch.Tensor]:
    """``torch.load`` with ``weights_only=True`` and pick ``key`` ('net' or 'trans')."""
    return load_checkpoint_entry(path, (key,), allow_pickle)[1]










def _require(state: Mapping[str, torch.Tensor], key: str, file: str) -> torch.Tensor:
    if key not in state:
        raise ValueError(f"{file}: missing tensor '{key}' (is this a T2M-GPT checkpoint?)")
    return state[key]


def _count(state: Mapping[str, torch.Tensor], pattern: str) -> int:
    regex = re.compile(pattern)
    return len({m.group(1) for k in state if (m := regex.fullmatch(k))})


# ---------------------------------------------------------------------------------------------- size inference

def infer_vq_config(state: Mapping[str, torch.Tensor], file: str = "VQ checkpoint") -> VQConfig:
    """VQConfig from the VQ-VAE tensors (keys without the ``vqvae.`` prefix)."""
    first = _require(state, "encoder.model.0.weight", file)  # [width, feat_dim, 3]
    width, feat_dim = int(first.shape[0]), int(first.shape[1])
    down_t = _count(state, r"encoder\.model\.(\d+)\.0\.weight")
    if down_t < 1:
        raise ValueError(f"{file}: no downsampling blocks 'encoder.model.N.0.weight'")
    depth = _count(state, r"encoder\.model\.2\.1\.model\.(\d+)\.conv1\.weight")
    if depth < 1:
        raise ValueError(f"{file}: no residual blocks 'encoder.model.2.1.model.N.conv1.weight'")
    if "quantizer.codebook" in state:
        codebook, quantizer, layers = state["quantizer.codebook"], "ema_reset", 1
    else:
        layers = _count(state, r"quantizer\.layers\.(\d+)\.codebook")
        if not layers:
            raise ValueError(f"{file}: missing tensor 'quantizer.codebook' (or 'quantizer.layers.N.codebook')")
        codebook, quantizer = state["quantizer.layers.0.codebook"], "residual"
    return VQConfig(feat_dim=feat_dim, width=width, code_dim=int(codebook.shape[1]), nb_code=int(codebook.shape[0]),
                    down_t=down_t, depth=depth, dilation_growth=RELEASE_DILATION_GROWTH, quantizer=quantizer,
                    residual_layers=layers)


def infer_gpt_config(state: Mapping[str, torch.Tensor], heads: int | None = None,
                     file: str = "GPT checkpoint") -> GPTConfig:
    """GPTConfig from the transformer tensors; heads = embed / 64 unless given."""
    tok = _require(state, "trans_base.tok_emb.weight", file)  # [K + 2, E]
    cond = _require(state, "trans_base.cond_emb.weight", file)  # [E, Dt]
    positions = _require(state, "trans_base.pos_embed.embed", file)  # [block, 1, E]
    embed = int(tok.shape[1])
    mlp = _require(state, "trans_base.blocks.0.mlp.0.weight", file) if "trans_base.blocks.0.mlp.0.weight" in state \
        else _require(state, "trans_head.blocks.0.mlp.0.weight", file)
    if heads is None:
        if embed % HEAD_DIM_ASSUMPTION:
            raise ValueError(f"{file}: embed {embed} is not a multiple of 64; pass --heads")
        heads = embed // HEAD_DIM_ASSUMPTION
    if heads < 1 or embed % heads:
        raise ValueError(f"--heads {heads} does not divide the embedding size {embed}")
    return GPTConfig(
        codebook_size=int(tok.shape[0]) - 2, embed=embed, n_head=heads,
        n_layer_base=_count(state, r"trans_base\.blocks\.(\d+)\.ln1\.weight"),
        n_layer_head=_count(state, r"trans_head\.blocks\.(\d+)\.ln1\.weight"),
        block_size=int(positions.shape[0]), dropout=0.0, text_dim=int(cond.shape[1]),
        ff_rate=int(mlp.shape[0]) // embed, length_conditioning="trans_base.len_emb.weight" in state,
    )




@dataclass
class ImportedModels:
    vq: MotionVQVAE
    gpt: MotionGPT
    mean: np.ndarray
    std: np.ndarray


def load_release(vq_path: str | Path, gpt_path: str | Path, mean_path: str | Path, std_path: str | Path,
                 heads: int | None = None, allow_pickle: bool = False) -> ImportedModels:
    """Rebuild the released VQ-VAE and GPT as our modules (strict loads) plus the de-normalisation arrays."""
    vq_state = strip_prefix(load_checkpoint_dict(vq_path, "net", allow_pickle), "vqvae.")
    vq = MotionVQVAE(infer_vq_config(vq_state, str(vq_path)))
    load_strict(vq, vq_state, str(vq_path))
    gpt_state = load_checkpoint_dict(gpt_path, "trans", allow_pickle)
    gpt = MotionGPT(infer_gpt_config(gpt_state, heads, str(gpt_path)))
    load_strict(gpt, gpt_state, str(gpt_path))
    if gpt.config.codebook_size != vq.config.nb_code:
        raise ValueError(f"{gpt_path}: GPT codebook_size {gpt.config.codebook_size} != VQ nb_code {vq.config.nb_code}")
    arrays = []
    for path in (mean_path, std_path):
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(str(path))
        array = np.load(path, allow_pickle=False).astype(np.float32).reshape(-1)
        if array.shape != (vq.config.feat_dim,):
            raise ValueError(f"{path}: expected [{vq.config.feat_dim}] values, got {list(array.shape)}")
        arrays.append(array)
    return ImportedModels(vq.eval(), gpt.eval(), arrays[0], arrays[1])


# ------------------------------------------------------------------------------------------------ text source

def bundle_text_source(bundle_dir: str | Path) -> TextSource:
    """Reuse the text graph + tokenizer of another (verified) bundle, e.g. an earlier import with CLIP."""
    from t2m.export.writing.verify import verify_bundle

    bundle_dir = Path(bundle_dir)
    manifest = verify_bundle(bundle_dir)
    if (manifest.get("quantization") or {}).get("text_encoder"):
        raise ValueError(f"{bundle_dir}: its text encoder is quantised; reuse a float32 one")
    entry = dict(manifest["text_encoder"])

    def write(out_dir: Path) -> dict:
        for name in ("text_encoder.onnx", "tokenizer.json"):
            shutil.copyfile(bundle_dir / name, out_dir / name)
        return entry

    return TextSource(write)


def import_t2m_gpt(
    vq_path: str | Path,
    gpt_path: str | Path,
    mean_path: str | Path,
    std_path: str | Path,
    out_dir: str | Path,
    *,
    clip_weights: str | Path | None = None,
    text_encoder_bundle: str | Path | None = None,
    heads: int | None = None,
    name: str = "t2m-gpt-humanml3d",
    version: str = "1.0.0",
    int8: str = "none",
    training_data: Mapping[str, str] | None = None,
    license: str = RELEASE_LICENSE,
    check_parity: bool = True,
    allow_pickle: bool = False,
    quantize: str | None = None,
    fixed_step: bool = False,
) -> tuple[dict, ExportChecks]:
    """The whole import: checkpoints -> our modules -> a verified bundle (guidance off, no unconditional branch);
    the step graph quantised with ``quantize`` (int8, int4 or fp16; kit.import_quantized), or int8 with ``int8``;
    ``fixed_step``: also gpt_step_fixed.onnx, the float32 step that T2M_CUDA_GRAPHS replays on a GPU."""
    if clip_weights is not None and text_encoder_bundle is not None:
        raise ValueError("pass either --clip or --text-encoder-bundle, not both")
    if quantize is not None and int8 in ("gpt", "all"):
        raise ValueError(f"--int8 {int8} and --quantize {quantize} both quantise the step graph: pass one (--int8 "
                         "text goes with --quantize)")
    # the text encoder first: a wrong CLIP file is refused before the slow checkpoint loads
    if clip_weights is not None:
        text_source = clip_text_source(clip_weights)
    elif text_encoder_bundle is not None:
        text_source = bundle_text_source(text_encoder_bundle)
    else:  # unreachable: refused above; keeps the types narrow
        raise ValueError(CLIP_REQUIRED)
    models = load_release(vq_path, gpt_path, mean_path, std_path, heads, allow_pickle)
    notes = (
        "## Imported weights\n\n"
        f"Imported from the released T2M-GPT checkpoints (`{Path(vq_path).name}`, `{Path(gpt_path).name}`).\n"
        f"Sizes inferred from tensor shapes; attention heads {models.gpt.config.n_head}"
        f" ({'given' if heads else 'assumed embed / 64'}); residual dilation growth {RELEASE_DILATION_GROWTH}"
        " (release value).\n"
        "Text features: OpenAI's CLIP ViT-B/32 encode_text (QuickGELU, features at the end token), float32, not"
        " normalised, on OpenAI's tokenization (the reference recipe).\n"
    )
    return import_quantized(out_dir, quantize, lambda out: export_bundle(
        out, vq=models.vq, gpt=models.gpt, mean=models.mean, std=models.std, text_source=text_source,
        name=name, version=version, unconditional_branch=False, default_guidance=1.0,
        training_data=dict(training_data or RELEASE_TRAINING_DATA), license=license, int8=int8, notes=notes,
        check_parity=check_parity, fixed_step=fixed_step,
    ))
