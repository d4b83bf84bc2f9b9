"""Text sources for bundles: a text graph + tokenizer.json writer per encoder (tiny random, MiniLM, CLIP), and the
one a token run recorded. Every family's exporter and the importers write their text graph through these."""
from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from t2m.export.graphs.text import export_text_graph, export_tiny_text_encoder, export_token_states_graph

__all__ = ["TextSource", "clip_text_source", "encoder_text_source", "minilm_text_source",
           "recorded_text_source", "save_text_tokenizer", "tiny_text_source",
           "token_states_text_source"]


@dataclass
class TextSource:
    """Writes text_encoder.onnx + tokenizer.json into a directory and returns the manifest's text_encoder entry.

    ``encoder`` (a t2m.model.networks.text_encoders.TextEncoder) is kept for the parity check when there is one.
    """

    write: Callable[[Path], dict]
    encoder: Any | None = None


def tiny_text_source(dim: int, max_length: int, seed: int = 0) -> TextSource:
    """The tiny random text graph (tests)."""
    return TextSource(lambda out_dir: export_tiny_text_encoder(out_dir, dim, max_length, seed=seed))


def encoder_text_source(encoder: Any) -> TextSource:
    """A t2m.model.networks.text_encoders.TextEncoder (MiniLM or CLIP): its export_module and its tokenizer."""

    def write(out_dir: Path) -> dict:
        save_text_tokenizer(encoder, out_dir / "tokenizer.json")
        ids, mask = encoder.tokenize(["a person walks forward", "someone jumps up and down twice"])
        export_text_graph(encoder.export_module(), out_dir / "text_encoder.onnx", ids, mask)
        return {"kind": encoder.name, "dim": int(encoder.dim), "max_length": int(encoder.max_length),
                "pooling": encoder.pooling, "normalize": bool(encoder.normalize), "null_condition": "zeros"}

    return TextSource(write, encoder)


def save_text_tokenizer(encoder: Any, path: Path) -> Path:
    """The encoder's tokenizer.json (CLIP's: OpenAI's tokenizer, built by t2m.model.networks.clip_tokenizer)."""
    if encoder.name == "clip":
        from t2m.model.networks.clip_tokenizer import save_clip_tokenizer

        return save_clip_tokenizer(path, context_length=int(encoder.max_length))
    return encoder.save_tokenizer(path)


def minilm_text_source() -> TextSource:
    from t2m.model.networks.text_encoders import MiniLMEncoder

    return encoder_text_source(MiniLMEncoder())


def clip_text_source(weights: str | Path) -> TextSource:
    from t2m.model.networks.text_encoders import ClipEncoder

    try:
        return encoder_text_source(ClipEncoder(weights))
    except ImportError as error:  # open_clip is an optional extra: a user error, not a crash
        raise ValueError(str(error)) from error


def token_states_text_source(encoder: Any) -> TextSource:
    """A t2m.families.diffusion.text_encoders.TokenStateEncoder (DiP's DistilBERT, MiniLM's states): the token-state
    graph (token_states) and its tokenizer.json; the manifest entry says ``pooling: tokens``."""

    def write(out_dir: Path) -> dict:
        encoder.save_tokenizer(out_dir / "tokenizer.json")
        ids, mask = encoder.tokenize(["a person walks forward", "someone jumps up and down twice"])
        export_token_states_graph(encoder.export_module(), out_dir / "text_encoder.onnx", ids, mask)
        return {"kind": encoder.name, "dim": int(encoder.dim), "max_length": int(encoder.max_length),
                "pooling": "tokens", "normalize": False, "null_condition": "zeros"}

    return TextSource(write, encoder)


def recorded_text_source(run: Path, run_data: Mapping[str, Any],
                         text_source: TextSource | None) -> tuple[str, Callable[[], TextSource]]:
    """The text encoder a token run recorded (kind, and a maker of its TextSource, called last: loading an encoder
    is the slow part); `text_source` given (tests) replaces it."""
    text = run_data.get("text_encoder") or {}
    kind = text.get("kind", "minilm") if isinstance(text, dict) else str(text)
    if text_source is not None:
        return kind, lambda: text_source
    if kind == "clip":
        if not text.get("clip_weights"):
            raise ValueError(f"{run}/config.json records no clip_weights for its clip text encoder")
        return kind, lambda: clip_text_source(text["clip_weights"])
    return kind, minilm_text_source
