"""DistilBERT (``distilbert-base-uncased``) as DiP and MDM+DistilBERT use it: the per-token states of the last layer.

Written out in one page with Hugging Face's parameter names, so a Hugging Face folder's ``model.safetensors`` /
``pytorch_model.bin`` loads strictly (docs: ../shared/docs/diffusion-models.md §2.2):

    embeddings.word_embeddings [vocab, dim], embeddings.position_embeddings [512, dim], embeddings.LayerNorm
    transformer.layer.{i}.attention.{q_lin, k_lin, v_lin, out_lin}    Linear(dim, dim)
    transformer.layer.{i}.sa_layer_norm                               post-norm after attention
    transformer.layer.{i}.ffn.{lin1 [hidden, dim], lin2 [dim, hidden]}, GELU (exact)
    transformer.layer.{i}.output_layer_norm                           post-norm after the feed-forward

    x = LayerNorm(word[ids] + position[0..L-1])                       (eps 1e-12, as transformers hard-codes)
    x = sa_layer_norm(x + out_lin(attention(q_lin x, k_lin x, v_lin x; keys = attention_mask)))
    x = output_layer_norm(x + lin2(gelu(lin1 x)))

The hub's file is DistilBertForMaskedLM's: keys under ``distilbert.`` plus the MLM head (``vocab_transform``,
``vocab_layer_norm``, ``vocab_projector``), which ``AutoModel`` drops; :func:`load_distilbert` does the same and
refuses anything else. The tokenizer is the uncased WordPiece of ``vocab.txt`` (or the folder's tokenizer.json) built
for the `tokenizers` library: lower-cased, accents stripped, ``[CLS] ... [SEP]``, padded with ``[PAD]`` = 0 to the
batch's longest; DiP's code does not truncate, so the only bound is the 512 learned positions.
"""
from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["DistilBert", "DistilBertConfig", "DistilBertFolder", "DistilBertTokenStates", "build_wordpiece_tokenizer",
           "distilbert_state", "load_distilbert", "locate_distilbert"]

LAYER_NORM_EPS = 1e-12
MLM_HEAD = ("vocab_transform.", "vocab_layer_norm.", "vocab_projector.")
IGNORED = ("embeddings.position_ids",)  # a buffer some older saves carry
PREFIX = "distilbert."
FOLDER = ("a distilbert-base-uncased folder (config.json, model.safetensors or pytorch_model.bin, vocab.txt or "
          "tokenizer.json)")


@dataclass(frozen=True)
class DistilBertConfig:
    """The sizes of ``config.json`` (defaults: distilbert-base-uncased, transformers' DistilBertConfig defaults)."""

    vocab_size: int = 30522
    max_position_embeddings: int = 512
    dim: int = 768
    n_layers: int = 6
    n_heads: int = 12
    hidden_dim: int = 3072
    pad_token_id: int = 0

    def __post_init__(self) -> None:
        if min(self.vocab_size, self.max_position_embeddings, self.dim, self.n_layers, self.n_heads,
               self.hidden_dim) < 1:
            raise ValueError(f"DistilBERT sizes must be positive: {self}")
        if self.dim % self.n_heads:
            raise ValueError(f"DistilBERT dim {self.dim} is not divisible by {self.n_heads} heads")

    @classmethod
    def from_json(cls, data: Mapping[str, Any], where: str = "config.json") -> DistilBertConfig:
        """A Hugging Face config.json; refuses another model type, sinusoidal positions or another activation
        (one line naming the field)."""
        model_type = data.get("model_type", "distilbert")
        if model_type != "distilbert":
            raise ValueError(f"{where}: model_type {model_type!r}, expected 'distilbert'")
        if data.get("sinusoidal_pos_embds", False):
            raise ValueError(f"{where}: sinusoidal_pos_embds is true; distilbert-base-uncased learns its positions")
        if data.get("activation", "gelu") != "gelu":
            raise ValueError(f"{where}: activation {data.get('activation')!r}, expected 'gelu'")
        fields = {name: int(data[name]) for name in ("vocab_size", "max_position_embeddings", "dim", "n_layers",
                                                     "n_heads", "hidden_dim", "pad_token_id") if name in data}
        try:
            return cls(**fields)
        except ValueError as error:
            raise ValueError(f"{where}: {error}") from None


class Attention(nn.Module):
    def __init__(self, dim: int, heads: int) -> None:
        super().__init__()
        self.heads = heads
        self.q_lin, self.k_lin, self.v_lin, self.out_lin = (nn.Linear(dim, dim) for _ in range(4))

    def _split(self, x: torch.Tensor) -> torch.Tensor:
        return x.unflatten(-1, (self.heads, -1)).transpose(1, 2)               # [B, H, L, D/H]

    def forward(self, x: torch.Tensor, keys: torch.Tensor) -> torch.Tensor:
        q, k, v = self._split(self.q_lin(x)), self._split(self.k_lin(x)), self._split(self.v_lin(x))
        y = F.scaled_dot_product_attention(q, k, v, attn_mask=keys[:, None, None, :])
        return self.out_lin(y.transpose(1, 2).flatten(2))


class FeedForward(nn.Module):
    def __init__(self, dim: int, hidden: int) -> None:
        super().__init__()
        self.lin1 = nn.Linear(dim, hidden)
        self.lin2 = nn.Linear(hidden, dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.lin2(F.gelu(self.lin1(x)))


class Block(nn.Module):
    def __init__(self, config: DistilBertConfig) -> None:
        super().__init__()
        self.attention = Attention(config.dim, config.n_heads)
        self.sa_layer_norm = nn.LayerNorm(config.dim, eps=LAYER_NORM_EPS)
        self.ffn = FeedForward(config.dim, config.hidden_dim)
        self.output_layer_norm = nn.LayerNorm(config.dim, eps=LAYER_NORM_EPS)

    def forward(self, x: torch.Tensor, keys: torch.Tensor) -> torch.Tensor:
        x = self.sa_layer_norm(x + self.attention(x, keys))
        return self.output_layer_norm(x + self.ffn(x))


class Embeddings(nn.Module):
    def __init__(self, config: DistilBertConfig) -> None:
        super().__init__()
        self.word_embeddings = nn.Embedding(config.vocab_size, config.dim)
        self.position_embeddings = nn.Embedding(config.max_position_embeddings, config.dim)
        self.LayerNorm = nn.LayerNorm(config.dim, eps=LAYER_NORM_EPS)

    def forward(self, input_ids: torch.Tensor) -> torch.Tensor:
        positions = self.position_embeddings.weight[: input_ids.shape[1]]
        return self.LayerNorm(self.word_embeddings(input_ids) + positions)


class Layers(nn.Module):
    def __init__(self, config: DistilBertConfig) -> None:
        super().__init__()
        self.layer = nn.ModuleList(Block(config) for _ in range(config.n_layers))


class DistilBert(nn.Module):
    """DistilBertModel's computation (eval): ids [B, L], attention_mask [B, L] (1 = real token) -> the last layer's
    states [B, L, dim] for every token (padded positions hold values; they are masked downstream)."""

    def __init__(self, config: DistilBertConfig) -> None:
        super().__init__()
        self.config = config
        self.embeddings = Embeddings(config)
        self.transformer = Layers(config)

    def forward(self, input_ids: torch.Tensor, attention_mask: torch.Tensor) -> torch.Tensor:
        x = self.embeddings(input_ids)
        keys = attention_mask.bool()
        for block in self.transformer.layer:
            x = block(x, keys)
        return x


class DistilBertTokenStates(nn.Module):
    """The token-state encoder's module: (input_ids, attention_mask) -> (text_states [B, L, dim] float32,
    text_mask [B, L] bool, True = a real token), what MDM's ``trans_dec`` takes as memory and its padding mask (the
    graph exports the states as ``token_states``; a token-state encoder of any BERT-like ``bert`` module with HF's
    ``last_hidden_state`` works too)."""

    def __init__(self, bert: nn.Module) -> None:
        super().__init__()
        self.bert = bert

    def forward(self, input_ids: torch.Tensor, attention_mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        states = self.bert(input_ids=input_ids, attention_mask=attention_mask)
        if not isinstance(states, torch.Tensor):
            states = states.last_hidden_state                              # a transformers model (MiniLM)
        return states, attention_mask != 0


# ------------------------------------------------------------------------------------------------ the HF folder

@dataclass(frozen=True)
class DistilBertFolder:
    """A Hugging Face folder's files: config.json, the weights, the tokenizer's source."""

    root: Path
    config: Path
    weights: Path
    tokenizer: Path          # tokenizer.json if present, else vocab.txt


def locate_distilbert(folder: str | Path) -> DistilBertFolder:
    """The files of a DistilBERT folder, each missing one refused in one line naming it."""
    root = Path(folder)
    if not root.is_dir():
        raise ValueError(f"{root}: no such folder (expected {FOLDER})")
    config = root / "config.json"
    if not config.is_file():
        raise ValueError(f"{config}: missing file: DistilBERT's sizes")
    weights = next((root / name for name in ("model.safetensors", "pytorch_model.bin") if (root / name).is_file()),
                   None)
    if weights is None:
        raise ValueError(f"{root}: missing file model.safetensors (or pytorch_model.bin): DistilBERT's weights")
    tokenizer = next((root / name for name in ("tokenizer.json", "vocab.txt") if (root / name).is_file()), None)
    if tokenizer is None:
        raise ValueError(f"{root}: missing file vocab.txt (or tokenizer.json): DistilBERT's uncased WordPiece")
    return DistilBertFolder(root, config, weights, tokenizer)


def read_weights(path: Path) -> dict[str, torch.Tensor]:
    """model.safetensors or pytorch_model.bin (plain tensors only), as float32 on the CPU."""
    try:
        if path.suffix == ".safetensors":
            from safetensors.torch import load_file

            state = load_file(str(path), device="cpu")
        else:
            state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:
        text = " ".join(str(error).split())[:200] or type(error).__name__
        raise ValueError(f"{path}: not a readable weights file ({text})") from None
    if not isinstance(state, Mapping) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise ValueError(f"{path}: not a state dict of tensors")
    return {str(k): v.float() if v.is_floating_point() else v for k, v in state.items()}


def distilbert_state(state: Mapping[str, torch.Tensor], module: DistilBert, where: str) -> dict[str, torch.Tensor]:
    """The encoder's tensors of a DistilBertModel or DistilBertForMaskedLM state dict (``distilbert.`` prefix and
    the MLM head dropped), every one present with its shape and nothing else: one line naming the first key that
    is wrong, with the shape expected."""
    expected = {key: tuple(value.shape) for key, value in module.state_dict().items()}
    found: dict[str, torch.Tensor] = {}
    for key, tensor in state.items():
        name = key[len(PREFIX):] if key.startswith(PREFIX) else key
        if name.startswith(MLM_HEAD) or name in IGNORED:
            continue
        if name not in expected:
            raise ValueError(f"{where}: unexpected tensor '{key}' (not part of distilbert-base-uncased's layout)")
        found[name] = tensor
    for key, shape in expected.items():
        text = "[" + ", ".join(map(str, shape)) + "]"
        if key not in found:
            raise ValueError(f"{where}: missing tensor '{key}' {text}")
        if tuple(found[key].shape) != shape:
            have = "[" + ", ".join(map(str, found[key].shape)) + "]"
            raise ValueError(f"{where}: tensor '{key}' has shape {have}, expected {text}")
    return found


def load_distilbert(folder: str | Path) -> DistilBert:
    """A Hugging Face DistilBERT folder -> :class:`DistilBert` (float32, eval, frozen), every tensor checked."""
    files = locate_distilbert(folder)
    try:
        data = json.loads(files.config.read_text(encoding="utf-8"))
    except (ValueError, OSError) as error:
        raise ValueError(f"{files.config}: not JSON ({' '.join(str(error).split())[:160]})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{files.config}: not a JSON object")
    module = DistilBert(DistilBertConfig.from_json(data, str(files.config)))
    module.load_state_dict(distilbert_state(read_weights(files.weights), module, str(files.weights)), strict=True)
    module.eval()
    for parameter in module.parameters():
        parameter.requires_grad_(False)
    return module


def build_wordpiece_tokenizer(source: str | Path, max_length: int = 512):
    """The uncased WordPiece tokenizer (`tokenizers`) of a vocab.txt or a tokenizer.json: ``[CLS] ... [SEP]``,
    truncated at ``max_length`` (the learned positions; DiP itself does not truncate), padded with [PAD] to the
    batch's longest text."""
    from tokenizers import Tokenizer, decoders, models, normalizers, pre_tokenizers, processors

    path = Path(source)
    if path.name == "tokenizer.json":
        tokenizer = Tokenizer.from_file(str(path))
    else:
        # what tokenizers' BertWordPieceTokenizer builds (HF's uncased BERT): clean text, Chinese characters split,
        # lower case and accents stripped, "##" continuations, words over 100 characters -> [UNK], [CLS] A [SEP]
        vocab = models.WordPiece.read_file(str(path))
        if "[CLS]" not in vocab or "[SEP]" not in vocab:
            raise ValueError(f"{path}: no [CLS] or [SEP] token: not an uncased BERT vocabulary")
        tokenizer = Tokenizer(models.WordPiece(vocab, unk_token="[UNK]", max_input_chars_per_word=100))
        tokenizer.normalizer = normalizers.BertNormalizer(clean_text=True, handle_chinese_chars=True,
                                                          strip_accents=None, lowercase=True)
        tokenizer.pre_tokenizer = pre_tokenizers.BertPreTokenizer()
        tokenizer.post_processor = processors.BertProcessing(("[SEP]", vocab["[SEP]"]), ("[CLS]", vocab["[CLS]"]))
        tokenizer.decoder = decoders.WordPiece(prefix="##")
    pad_id = tokenizer.token_to_id("[PAD]")
    if pad_id is None or tokenizer.token_to_id("[CLS]") is None or tokenizer.token_to_id("[SEP]") is None:
        raise ValueError(f"{path}: no [PAD], [CLS] or [SEP] token: not an uncased BERT vocabulary")
    tokenizer.enable_truncation(max_length=max_length)
    tokenizer.enable_padding(pad_id=pad_id, pad_token="[PAD]")
    return tokenizer
