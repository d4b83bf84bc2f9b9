"""CLIP's tokenizer.json for bundles: the tokenizer itself lives in ``t2m.model.networks.clip_tokenizer`` (training
tokenises with it too); this name is kept for the exporter."""
from __future__ import annotations

from t2m.model.networks.clip_tokenizer import build_clip_tokenizer, save_clip_tokenizer

__all__ = ["build_clip_tokenizer", "save_clip_tokenizer"]
