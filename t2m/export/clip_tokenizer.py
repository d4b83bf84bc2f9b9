"""CLIP's BPE tokenizer as a `tokenizers` tokenizer.json (the service tokenizes with the `tokenizers` library only).

open_clip ships its vocabulary as ``bpe_simple_vocab_16e6.txt.gz`` (a merges list) and tokenizes in
Python. This rebuilds the same tokenizer: byte-level symbols with ``</w>`` marking word ends, the
first 48,894 merges, ``<start_of_text>`` (49406) and ``<end_of_text>`` (49407) around the text,
lower-casing and whitespace collapsing, truncation to the context length with the end token kept
last, and zero padding to the full context (open_clip's text tower needs all 77 positions; it
pools at the end token, found as the largest id). Not reproduced: open_clip's ``ftfy`` repair of
broken Unicode and HTML unescaping (plain captions are unaffected).
"""
from __future__ import annotations

import gzip
from pathlib import Path

CONTEXT_LENGTH = 77
CLIP_MERGES = 49152 - 256 - 2  # open_clip uses merges[1 : 49152 - 256 - 2 + 1]
START, END = "<start_of_text>", "<end_of_text>"
# open_clip's word pattern without its special-token alternatives
WORD_PATTERN = r"""'s|'t|'re|'ve|'m|'ll|'d|[\p{L}]+|[\p{N}]|[^\s\p{L}\p{N}]+"""


def bytes_to_unicode() -> dict[int, str]:
    """The reversible byte -> printable character table of byte-level BPE (printable bytes map to themselves)."""
    printable = list(range(ord("!"), ord("~") + 1)) + list(range(ord("¡"), ord("¬") + 1)) + list(range(ord("®"), ord("ÿ") + 1))
    chars = printable[:]
    extra = 0
    for byte in range(256):
        if byte not in printable:
            printable.append(byte)
            chars.append(256 + extra)
            extra += 1
    return dict(zip(printable, (chr(c) for c in chars)))


def default_bpe_path() -> Path:
    try:
        from open_clip.tokenizer import default_bpe
    except ImportError as error:
        from t2m.model.networks.text_encoders import OPEN_CLIP_MISSING

        raise ImportError(OPEN_CLIP_MISSING) from error
    return Path(default_bpe())


def read_merges(bpe_path: str | Path, limit: int = CLIP_MERGES) -> list[tuple[str, str]]:
    lines = gzip.open(bpe_path, "rt", encoding="utf-8").read().split("\n")
    merges = [tuple(line.split()) for line in lines[1 : limit + 1] if line.strip()]
    for index, merge in enumerate(merges):
        if len(merge) != 2:
            raise ValueError(f"{bpe_path}: line {index + 2} is not a merge of two symbols: {' '.join(merge)!r}")
    return merges  # type: ignore[return-value]


def build_clip_tokenizer(bpe_path: str | Path | None = None, context_length: int = CONTEXT_LENGTH):
    """A `tokenizers.Tokenizer` equivalent to open_clip's SimpleTokenizer + tokenize(..., truncate=True)."""
    from tokenizers import Regex, Tokenizer, decoders, models, normalizers, pre_tokenizers, processors

    merges = read_merges(bpe_path or default_bpe_path())
    symbols = list(bytes_to_unicode().values())
    vocab_list = symbols + [s + "</w>" for s in symbols] + ["".join(m) for m in merges] + [START, END]
    vocab = {token: index for index, token in enumerate(vocab_list)}
    tokenizer = Tokenizer(models.BPE(vocab=vocab, merges=merges, end_of_word_suffix="</w>", fuse_unk=False))
    tokenizer.normalizer = normalizers.Sequence(
        [normalizers.NFC(), normalizers.Replace(Regex(r"\s+"), " "), normalizers.Strip(), normalizers.Lowercase()]
    )
    tokenizer.pre_tokenizer = pre_tokenizers.Sequence([
        pre_tokenizers.Split(Regex(WORD_PATTERN), behavior="removed", invert=True),
        pre_tokenizers.ByteLevel(add_prefix_space=False, use_regex=False),
    ])
    tokenizer.decoder = decoders.ByteLevel()
    tokenizer.add_special_tokens([START, END])
    tokenizer.post_processor = processors.TemplateProcessing(
        single=f"{START} $A {END}", special_tokens=[(START, vocab[START]), (END, vocab[END])]
    )
    tokenizer.enable_truncation(max_length=context_length)
    tokenizer.enable_padding(length=context_length, pad_id=0, pad_token=vocab_list[0])  # open_clip pads with id 0
    return tokenizer


def save_clip_tokenizer(path: str | Path, context_length: int = CONTEXT_LENGTH, bpe_path: str | Path | None = None) -> Path:
    path = Path(path)
    build_clip_tokenizer(bpe_path, context_length).save(str(path))
    return path
