"""Import MDM's released checkpoints (GuyTevet/motion-diffusion-model): the front half of ``t2m import mdm``.

Releases (../shared/docs/diffusion-models.md §4.2): the paper model ``humanml_trans_enc_512`` (trans_enc + CLIP,
1000 steps), the 50-step model (trans_enc + CLIP, 50 steps), the DistilBERT variant
``humanml_trans_dec_512_bert-50steps`` (trans_dec + DistilBERT token states, 50 steps, EMA, mask_frames), and any
folder the official trainer writes with those settings. :func:`load_mdm_release` reads the folder's args.json
(sizes, steps, flags; missing keys take the parser's defaults; ff 1024, 4 heads, dropout 0.1 and GELU are the
code's constants), the text encoder (OpenAI's ViT-B-32.pt cut to 20 tokens, or a DistilBERT folder) and the
weights (``model_avg`` iff use_ema), every tensor checked and loaded strictly. DiP (``context_len`` > 0) is
:mod:`t2m.families.diffusion.import_dip`'s. Bundle writing is the family's exporter's (not here).
"""
from __future__ import annotations

from pathlib import Path

from t2m.families.diffusion.mdm_files import ImportedDiffusion, load_release
from t2m.families.diffusion.network import DiffusionConfig

__all__ = ["check_mdm_config", "load_mdm_release"]


def check_mdm_config(args: dict, config: DiffusionConfig, where: str) -> None:
    """What an MDM import refuses beyond the modules' own checks: a DiP release (prefix completion) and trans_dec's
    ``emb_trans_dec`` (the 2022 code prepended time + text, the current code time only: which one a release was
    trained with cannot be told from its files)."""
    if config.context_len > 0:
        raise ValueError(f"{where}: context_len {config.context_len}: a DiP release (prefix completion); import it "
                         "with t2m import dip")
    if config.arch == "trans_dec" and config.emb_trans_dec:
        raise ValueError(f"{where}: arch 'trans_dec' with emb_trans_dec: its meaning changed between code versions "
                         "(2022: time + text token, 2025: time token), so the release cannot be computed exactly")


def load_mdm_release(folder: str | Path | None, clip_file: str | Path | None = None,
                     bert_dir: str | Path | None = None, *, model_file: str | Path | None = None,
                     allow_pickle: bool = False) -> ImportedDiffusion:
    """An MDM release folder -> (config, denoiser, text encoder) and what was read; ``clip_file`` for a CLIP
    release, ``bert_dir`` for the DistilBERT variant; ``model_file`` when the folder holds several weights files.
    Cheap checks first (files, args.json, the text encoder's file), then the text encoder, then the weights."""
    return load_release("MDM", check_mdm_config, folder, clip_file, bert_dir, model_file, allow_pickle)
