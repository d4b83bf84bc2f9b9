"""Import DiP (``DiP_no-target_10steps_context20_predict40``; GuyTevet/motion-diffusion-model's DiP.md, also in
``guytevet/CLoSD``): the front half of ``t2m import dip``.

DiP is MDM's trans_dec over DistilBERT token states with prefix completion: each call denoises ``pred_len`` (40)
new frames in 10 steps after ``context_len`` (20) clean prefix frames (../shared/docs/diffusion-models.md §5).
:func:`load_dip_release` reads the folder's args.json, the DistilBERT folder and the weights (``model_avg`` iff
use_ema), every tensor checked and loaded strictly. Refused: a release without prefix completion (an MDM: t2m import
mdm), another text encoder or arch, target conditioning (``multi_target_cond`` / ``lambda_target_loc``: the target
variant's extra ``embed_target_cond.*`` modules are not built). Bundle writing is the family's exporter's.
"""
from __future__ import annotations

from pathlib import Path

from t2m.families.diffusion.mdm_files import ImportedDiffusion, load_release
from t2m.families.diffusion.network import DiffusionConfig

__all__ = ["check_dip_config", "load_dip_release"]


def check_dip_config(args: dict, config: DiffusionConfig, where: str) -> None:
    """A DiP release: prefix completion (context_len > 0) over DistilBERT token states with trans_dec."""
    if config.context_len <= 0:
        raise ValueError(f"{where}: context_len {config.context_len}: not a DiP release (no prefix completion); "
                         "import it with t2m import mdm")
    if config.arch != "trans_dec" or not config.text_tokens:
        encoder = args.get("text_encoder_type", "clip")
        raise ValueError(f"{where}: arch {config.arch!r} with text_encoder_type {encoder!r}: DiP is trans_dec over "
                         "DistilBERT token states ('bert'); the official sampler refuses a CLIP DiP's per-call texts")


def load_dip_release(folder: str | Path | None, bert_dir: str | Path | None = None, *,
                     model_file: str | Path | None = None, allow_pickle: bool = False) -> ImportedDiffusion:
    """A DiP release folder + a DistilBERT folder -> (config, denoiser, text encoder) and what was read; cheap checks
    first (files, args.json, the DistilBERT folder), then DistilBERT, then the weights."""
    return load_release("DiP", check_dip_config, folder, None, bert_dir, model_file, allow_pickle)
