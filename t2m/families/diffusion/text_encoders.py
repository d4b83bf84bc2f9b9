"""The text encoders of the diffusion family (MDM, DiP; ../shared/docs/diffusion-models.md §2).

- **MDM's CLIP path** (``text_encoder_type='clip'``): OpenAI's CLIP ViT-B/32 text tower (the project's exact tower,
  :mod:`t2m.model.networks.clip_text`), the caption cut to **20 BPE tokens**: ``clip.tokenize(texts,
  context_length=22, truncate=True)`` = start token + the first 20 tokens + the end token forced into the last
  slot, zero padded (MDM pads to 77; the causal attention never lets the end token see the padding, so padding to
  the batch's longest gives the same feature). The feature is ``encode_text``: the end token's state times
  ``text_projection``, 512-d, **not normalised**. MDM runs the tower in **float16** (``convert_weights``: linear and
  attention weights and ``text_projection`` in half, LayerNorms computed in float32 and cast back, activations in
  half) and casts the result to float32. :class:`MdmClipEncoder` gives the feature in float32 arithmetic (what the
  service's graph computes); :func:`mdm_clip_features` with ``precision="float16"`` emulates MDM's half arithmetic
  with the same casts, to measure the difference (tests/families/diffusion/test_diffusion_text.py).
- **DiP's DistilBERT token states** (``text_encoder_type='bert'``): :class:`TokenStateEncoder` over
  :mod:`t2m.families.diffusion.distilbert`: every token's last-layer state [B, L, 768] and the padding mask, no pooling,
  no truncation in DiP's code (512 positions bound it here).
- **MiniLM token states**: the same outputs from the all-MiniLM-L6-v2 BERT the project ships (384-d, 64 word
  pieces), for a diffusion model trained here.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from t2m.families.diffusion.distilbert import DistilBertTokenStates, build_wordpiece_tokenizer, load_distilbert
from t2m.model.networks.clip_text import ClipTextTransformer, ResidualAttentionBlock
from t2m.model.networks.text_encoders import MINILM_MAX_LENGTH, ClipEncoder, TokenizedModule, minilm_model_dir

if TYPE_CHECKING:
    from tokenizers import Tokenizer

    from t2m.export.kit.text_sources import TextSource

__all__ = ["MDM_CLIP_CONTEXT", "MDM_MAX_TEXT_TOKENS", "MdmClipEncoder", "TokenStateCache", "TokenStateEncoder",
           "cache_token_states", "clip_encode_text_fp16", "distilbert_encoder", "mdm_clip_features",
           "minilm_token_encoder"]

MDM_MAX_TEXT_TOKENS = 20                        # mdm.py: max_text_len = 20 for humanml / kit
MDM_CLIP_CONTEXT = MDM_MAX_TEXT_TOKENS + 2      # clip.tokenize(..., context_length=22, truncate=True)


class MdmClipEncoder(ClipEncoder):
    """MDM's CLIP text feature in float32: OpenAI's tokenizer cut to 22 ids (20 BPE tokens + start/end, the end
    token kept last), ``encode_text`` pooled at the end token, not normalised. The same text-graph contract as the
    other CLIP bundles (kind ``clip``, ``max_length`` 22)."""

    module: ClipTextTransformer

    def __init__(self, weights: str | Path) -> None:
        from t2m.model.networks.clip_tokenizer import build_clip_tokenizer

        super().__init__(weights)
        if self.module.config.context_length < MDM_CLIP_CONTEXT:
            raise ValueError(f"{weights}: CLIP context {self.module.config.context_length} < {MDM_CLIP_CONTEXT}")
        self.max_length = MDM_CLIP_CONTEXT
        self.tokenizer = build_clip_tokenizer(context_length=MDM_CLIP_CONTEXT)


def _layer_norm_fp32(norm: nn.LayerNorm, x: torch.Tensor) -> torch.Tensor:
    """OpenAI's LayerNorm subclass: computed in float32, cast back to the input's type."""
    return norm(x.float()).to(x.dtype)


@torch.no_grad()
def clip_encode_text_fp16(clip: ClipTextTransformer, input_ids: torch.Tensor) -> torch.Tensor:
    """``encode_text`` as OpenAI's code computes it after ``convert_weights`` (MDM): embeddings cast to half, the
    blocks' linear / attention weights and ``text_projection`` in half, LayerNorms in float32 cast back to half;
    result cast to float32. An emulation on the CPU (torch's half kernels): the GPU's half kernels round otherwise."""
    half = torch.float16
    length = input_ids.shape[1]
    x = clip.token_embedding(input_ids).to(half) + clip.positional_embedding[:length].to(half)
    mask = clip.causal_mask[:length, :length].to(half)
    for block in clip.transformer.resblocks:
        assert isinstance(block, ResidualAttentionBlock)
        attn, mlp = block.attn, block.mlp
        h = _layer_norm_fp32(block.ln_1, x)
        q, k, v = F.linear(h, attn.in_proj_weight.to(half), attn.in_proj_bias.to(half)).chunk(3, dim=-1)
        q, k, v = (t.unflatten(-1, (attn.heads, -1)).transpose(1, 2) for t in (q, k, v))
        y = F.scaled_dot_product_attention(q, k, v, attn_mask=mask).transpose(1, 2).flatten(2)
        x = x + F.linear(y, attn.out_proj.weight.to(half), attn.out_proj.bias.to(half))
        h = _layer_norm_fp32(block.ln_2, x)
        h = F.linear(h, mlp.c_fc.weight.to(half), mlp.c_fc.bias.to(half))
        h = h * torch.sigmoid(1.702 * h)
        x = x + F.linear(h, mlp.c_proj.weight.to(half), mlp.c_proj.bias.to(half))
    x = _layer_norm_fp32(clip.ln_final, x)
    pooled = x[torch.arange(x.shape[0]), input_ids.argmax(dim=-1)]
    return (pooled @ clip.text_projection.to(half)).float()


@torch.no_grad()
def mdm_clip_features(encoder: MdmClipEncoder, texts: list[str],
                      precision: Literal["float32", "float16"] = "float32") -> np.ndarray:
    """MDM's text vectors [N, 512] float32 for ``texts``: float32 arithmetic (the service's) or MDM's float16
    arithmetic emulated (:func:`clip_encode_text_fp16`)."""
    if precision not in ("float32", "float16"):
        raise ValueError(f"precision must be 'float32' or 'float16', got {precision!r}")
    input_ids, attention_mask = encoder.tokenize(list(texts))
    if precision == "float16":
        return clip_encode_text_fp16(encoder.module, input_ids).numpy()
    return encoder.module(input_ids, attention_mask).float().numpy()


class TokenStateEncoder(TokenizedModule):
    """A frozen token-state text encoder: a `tokenizers` Tokenizer (set to its truncation and padding) and a module
    (input_ids, attention_mask) -> (text_states [N, L, dim], text_mask [N, L] bool); the token-state text graph
    exports the states (``token_states``), the service masks padding from the tokenizer's attention mask.
    ``pooling`` is ``"tokens"``: nothing is pooled."""

    pooling = "tokens"
    normalize = False

    def __init__(self, name: str, tokenizer: Tokenizer, module: nn.Module, dim: int, max_length: int) -> None:
        self.name, self.tokenizer, self.dim, self.max_length = name, tokenizer, dim, max_length
        self.module = module.eval()
        for parameter in self.module.parameters():
            parameter.requires_grad_(False)

    @torch.no_grad()
    def encode(self, texts: list[str]) -> tuple[np.ndarray, np.ndarray]:
        """(states float32 [N, L, dim], mask bool [N, L]) of one batch (L: its longest text)."""
        states, mask = self.module(*self.tokenize(texts))
        return states.float().numpy(), mask.numpy()


def distilbert_encoder(folder: str | Path, max_length: int | None = None) -> TokenStateEncoder:
    """DiP's text encoder from a Hugging Face ``distilbert-base-uncased`` folder (config.json, model.safetensors or
    pytorch_model.bin, tokenizer.json or vocab.txt); ``max_length`` defaults to the learned positions (512: DiP's
    code does not truncate, so this is its only bound)."""
    from t2m.families.diffusion.distilbert import locate_distilbert

    files = locate_distilbert(folder)
    bert = load_distilbert(files.root)
    max_length = bert.config.max_position_embeddings if max_length is None else max_length
    if max_length > bert.config.max_position_embeddings:
        raise ValueError(f"max_length {max_length} exceeds DistilBERT's {bert.config.max_position_embeddings} "
                         "positions")
    tokenizer = build_wordpiece_tokenizer(files.tokenizer, max_length)
    if tokenizer.get_vocab_size() != bert.config.vocab_size:
        raise ValueError(f"{files.tokenizer}: {tokenizer.get_vocab_size()} tokens, the weights have "
                         f"{bert.config.vocab_size} rows")
    return TokenStateEncoder("distilbert", tokenizer, DistilBertTokenStates(bert), bert.config.dim, max_length)


def minilm_token_encoder(model_dir: str | Path | None = None, max_length: int = MINILM_MAX_LENGTH
                         ) -> TokenStateEncoder:
    """all-MiniLM-L6-v2's token states (384-d), as the project's MiniLM encoder tokenises (64 word pieces), for a
    diffusion model trained here: the last layer's states, not pooled, not normalised."""
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
    from transformers import AutoModel

    root = Path(model_dir) if model_dir else minilm_model_dir()
    tokenizer = build_wordpiece_tokenizer(root / "tokenizer.json", max_length)
    bert = AutoModel.from_pretrained(str(root), local_files_only=True)
    return TokenStateEncoder("minilm-tokens", tokenizer, DistilBertTokenStates(bert), int(bert.config.hidden_size),
                             max_length)


@dataclass
class TokenStateCache:
    """Every caption's token states, stored once: ``states`` [sum of lengths, dim] (float16: half the memory; the
    trained model reads them as float32), caption i's real tokens at ``offsets[i]:offsets[i + 1]``."""

    encoder: str
    texts: list[str]
    offsets: np.ndarray     # int64 [N + 1]
    states: np.ndarray      # float16 [total tokens, dim]

    def __post_init__(self) -> None:
        self.index = {text: i for i, text in enumerate(self.texts)}

    @property
    def dim(self) -> int:
        return int(self.states.shape[1])

    def batch(self, rows: list[int]) -> tuple[torch.Tensor, torch.Tensor]:
        """(text float32 [B, L, dim] zero-padded, text_mask bool [B, L]) of the captions at ``rows`` (L: their
        longest)."""
        lengths = [int(self.offsets[r + 1] - self.offsets[r]) for r in rows]
        text = torch.zeros(len(rows), max(lengths), self.dim)
        mask = torch.zeros(len(rows), max(lengths), dtype=torch.bool)
        for b, (row, length) in enumerate(zip(rows, lengths)):
            start = int(self.offsets[row])
            text[b, :length] = torch.from_numpy(self.states[start:start + length].astype(np.float32))
            mask[b, :length] = True
        return text, mask


def cache_token_states(source: object, encoder: TokenStateEncoder, path: str | Path,
                       batch_size: int = 128) -> TokenStateCache:
    """Encode every caption of ``source`` (readers or captions, as cache_text_features takes them) once, keeping its
    real tokens' states; an existing cache of the same encoder is reused and only new captions are encoded."""
    from tqdm import tqdm

    from t2m.model.networks.text_encoders import collect_captions

    path = Path(path)
    texts = collect_captions(source)
    known: dict[str, np.ndarray] = {}
    if path.is_file():
        with np.load(path, allow_pickle=False) as stored:
            if str(stored["encoder"]) == encoder.name and stored["states"].shape[1] == encoder.dim:
                offsets, states = stored["offsets"], stored["states"]
                known = {text: states[offsets[i]:offsets[i + 1]] for i, text in enumerate(stored["texts"].tolist())}
    missing = [t for t in texts if t not in known]
    if missing:
        progress = tqdm(total=len(missing), desc=f"token states ({encoder.name})", unit="caption")
        for start in range(0, len(missing), batch_size):
            chunk = missing[start:start + batch_size]
            states, mask = encoder.encode(chunk)
            for text, row, real in zip(chunk, states, mask):
                known[text] = row[real].astype(np.float16)
            progress.update(len(chunk))
        progress.close()
        all_texts = list(known)
        lengths = np.array([len(known[t]) for t in all_texts], np.int64)
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, "wb") as handle:  # a file handle: numpy would append .npz to other names
            np.savez(handle, texts=np.array(all_texts, dtype=np.str_), offsets=np.append(0, np.cumsum(lengths)),
                     states=np.concatenate([known[t] for t in all_texts]).astype(np.float16),
                     encoder=np.array(encoder.name))
    lengths = np.array([len(known[t]) for t in texts], np.int64)
    return TokenStateCache(encoder.name, texts, np.append(0, np.cumsum(lengths)),
                           np.concatenate([known[t] for t in texts]).astype(np.float16))


def mdm_clip_text_source(weights: str | Path) -> TextSource:
    """MDM's CLIP text path (t2m.families.diffusion.text_encoders.MdmClipEncoder): the CLIP graph of the other
    families with OpenAI's tokenizer cut to 22 ids (20 BPE tokens), features in float32."""
    from t2m.export.kit.text_sources import encoder_text_source

    return encoder_text_source(MdmClipEncoder(weights))
