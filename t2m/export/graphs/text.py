"""text_encoder.onnx + tokenizer.json: text -> the condition vector the GPT was trained with.

Graph: input_ids int64 [B, L], attention_mask int64 [B, L] -> text_features float32 [B, Dt], with the
pooling and normalisation of training inside, so the service only tokenizes and runs it.
The tokenizer file is written with the bundle's truncation (max_length) and padding to the batch's
longest text, so ``Tokenizer.from_file(...).encode_batch(texts)`` gives ready-to-feed ids and masks.

Also holds a tiny random text encoder and tokenizer (:func:`tiny_text_encoder`) for fast test bundles.
"""
from __future__ import annotations

from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from t2m.export.graphs.export import export_graph


def export_text_graph(module: nn.Module, path: str | Path, example_ids: torch.Tensor,
                      example_mask: torch.Tensor) -> Path:
    """Write text_encoder.onnx from ``module(input_ids, attention_mask) -> [B, Dt]`` (B and L dynamic)."""
    input_names = ["input_ids", "attention_mask"]
    path = export_graph(
        module.eval(),
        (example_ids, example_mask),
        path,
        input_names=input_names,
        output_names=["text_features"],
        dynamic_axes={"input_ids": {0: "batch", 1: "tokens"}, "attention_mask": {0: "batch", 1: "tokens"},
                      "text_features": {0: "batch"}},
    )
    _restore_dropped_inputs(path, input_names)
    return path


class _StatesOnly(nn.Module):
    """A token-state module's states alone: encoders that also return their padding mask (DistilBertTokenStates)
    give it up here, since the service masks the padding from the tokenizer's own attention mask."""

    def __init__(self, module: nn.Module) -> None:
        super().__init__()
        self.module = module

    def forward(self, input_ids: torch.Tensor, attention_mask: torch.Tensor) -> torch.Tensor:
        out = self.module(input_ids, attention_mask)
        return out[0] if isinstance(out, tuple) else out


def export_token_states_graph(module: nn.Module, path: str | Path, example_ids: torch.Tensor,
                              example_mask: torch.Tensor) -> Path:
    """Write a token-state text graph (DiP's DistilBERT, MiniLM's states; the diffusion family's contract,
    t2m/families/diffusion/family.py) from ``module(input_ids, attention_mask) -> [B, L, Dt]`` (or ``(states, mask)``):
    input_ids, attention_mask int64 [B, L] -> token_states float32 [B, L, Dt], every token's state, nothing pooled,
    B and L dynamic; padded positions hold values the denoiser's text_mask hides."""
    names = ["input_ids", "attention_mask"]
    path = export_graph(_StatesOnly(module).eval(), (example_ids, example_mask), path, input_names=names,
                        output_names=["token_states"],
                        dynamic_axes={name: {0: "batch", 1: "tokens"} for name in [*names, "token_states"]})
    _restore_dropped_inputs(path, names)
    return path


def _restore_dropped_inputs(path: str | Path, names: list[str]) -> None:
    """Put back inputs the exporter dropped because the module ignores them (CLIP's tower finds the end token
    without the mask), so that every text graph has the contract's two inputs and is fed the same way."""
    import onnx

    model = onnx.load(str(path))
    present = {graph_input.name for graph_input in model.graph.input}
    missing = [name for name in names if name not in present]
    if missing:
        for name in missing:
            model.graph.input.append(
                onnx.helper.make_tensor_value_info(name, onnx.TensorProto.INT64, ["batch", "tokens"]))
        onnx.save(model, str(path))


def write_tokenizer(tokenizer, path: str | Path, max_length: int, pad_token: str, pad_id: int) -> Path:
    """Save a ``tokenizers.Tokenizer`` configured as the service will use it: truncate at max_length, pad to longest."""
    tokenizer.enable_truncation(max_length=max_length)
    tokenizer.enable_padding(pad_id=pad_id, pad_token=pad_token)  # no `length`: pad to the batch's longest
    path = Path(path)
    tokenizer.save(str(path))
    return path


def tokenize(tokenizer_path: str | Path, texts: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
    """Tokenize like the service does (the bundle's tokenizer.json as saved) -> (input_ids, attention_mask) int64."""
    from tokenizers import Tokenizer

    encodings = Tokenizer.from_file(str(tokenizer_path)).encode_batch(texts)
    ids = torch.tensor([e.ids for e in encodings], dtype=torch.long)
    mask = torch.tensor([e.attention_mask for e in encodings], dtype=torch.long)
    return ids, mask


# ------------------------------------------------------------------------------- tiny random encoder (tests)

TINY_CORPUS = (
    "a person walks forward slowly and then turns around",
    "a man jumps up and down twice",
    "someone waves with the right hand while standing still",
    "the person runs in a circle and stops",
    "a woman sits down on a chair, then stands up again",
    "a figure kicks with the left leg and raises both arms",
    "walking backwards, the person bows politely",
    "he dances happily, spinning to the left",
    "a tired person limps to the right",
    "she throws a ball with her left hand and crouches",
)
TINY_SPECIAL = ("[PAD]", "[UNK]", "[CLS]", "[SEP]")


def build_tiny_tokenizer(vocab_size: int = 200):
    """A BERT-style WordPiece tokenizer trained on a few motion sentences (lower-cased, [CLS] ... [SEP])."""
    from tokenizers import Tokenizer, decoders, models, normalizers, pre_tokenizers, processors, trainers

    tokenizer = Tokenizer(models.WordPiece(unk_token="[UNK]"))
    tokenizer.normalizer = normalizers.BertNormalizer(lowercase=True)
    tokenizer.pre_tokenizer = pre_tokenizers.BertPreTokenizer()
    tokenizer.decoder = decoders.WordPiece()
    trainer = trainers.WordPieceTrainer(vocab_size=vocab_size, special_tokens=list(TINY_SPECIAL), show_progress=False)
    tokenizer.train_from_iterator(TINY_CORPUS, trainer=trainer)
    cls_id, sep_id = tokenizer.token_to_id("[CLS]"), tokenizer.token_to_id("[SEP]")
    tokenizer.post_processor = processors.TemplateProcessing(
        single="[CLS] $A [SEP]", pair="[CLS] $A [SEP] $B:1 [SEP]:1",
        special_tokens=[("[CLS]", cls_id), ("[SEP]", sep_id)],
    )
    return tokenizer


class TinyTextEncoder(nn.Module):
    """Random token embeddings -> masked mean -> linear -> L2 normalisation: the shape of MiniLM's pipeline, tiny."""

    def __init__(self, vocab_size: int, dim: int, seed: int = 0) -> None:
        super().__init__()
        generator = torch.Generator().manual_seed(seed)
        self.embed = nn.Embedding(vocab_size, dim)
        self.proj = nn.Linear(dim, dim)
        with torch.no_grad():
            self.embed.weight.copy_(torch.randn(vocab_size, dim, generator=generator))
            self.proj.weight.copy_(torch.randn(dim, dim, generator=generator) / dim**0.5)
            self.proj.bias.zero_()

    def forward(self, input_ids: torch.Tensor, attention_mask: torch.Tensor) -> torch.Tensor:
        mask = attention_mask.unsqueeze(-1).to(torch.float32)
        pooled = (self.embed(input_ids) * mask).sum(dim=1) / mask.sum(dim=1).clamp(min=1.0)
        return F.normalize(self.proj(pooled), dim=-1)


def export_tiny_text_encoder(out_dir: str | Path, dim: int, max_length: int, seed: int = 0) -> dict:
    """Write text_encoder.onnx + tokenizer.json of a tiny random encoder; return the manifest's text_encoder entry."""
    out_dir = Path(out_dir)
    tokenizer = build_tiny_tokenizer()
    tokenizer_path = write_tokenizer(tokenizer, out_dir / "tokenizer.json", max_length, "[PAD]",
                                     tokenizer.token_to_id("[PAD]"))
    encoder = TinyTextEncoder(tokenizer.get_vocab_size(), dim, seed=seed)
    ids, mask = tokenize(tokenizer_path, ["a person walks", "a man jumps up and down twice"])
    export_text_graph(encoder, out_dir / "text_encoder.onnx", ids, mask)
    return {"kind": "tiny-random", "dim": dim, "max_length": max_length, "pooling": "mean", "normalize": True,
            "null_condition": "zeros"}
