"""OpenAI CLIP's tokenization rules written out plainly in Python (test reference, independent of `tokenizers`).

The same published algorithm as OpenAI's ``clip.tokenize(text, truncate=True)``: clean (ftfy.fix_text when ftfy is
installed, html.unescape twice, whitespace runs -> one space, strip, str.lower), split with OpenAI's word pattern
(special-token literals first), byte-level symbols with ``</w>`` on the last, merge the lowest-ranked adjacent pair
everywhere until none is in the merges list, look the symbols up, add start/end, truncate keeping the end token.
"""
from __future__ import annotations

import html
import itertools
from functools import cache
from pathlib import Path

import regex

from t2m.model.networks.clip_tokenizer import CLIP_MERGES, END, START, VOCAB_FILE, bytes_to_unicode, read_merges

PATTERN = regex.compile(
    r"""<\|startoftext\|>|<\|endoftext\|>|'s|'t|'re|'ve|'m|'ll|'d|[\p{L}]+|[\p{N}]|[^\s\p{L}\p{N}]+""",
    regex.IGNORECASE)


def have_ftfy() -> bool:
    try:
        import ftfy  # noqa: F401
    except ImportError:
        return False
    return True


def clean(text: str, use_ftfy: bool = True) -> str:
    if use_ftfy:
        import ftfy

        text = ftfy.fix_text(text)
    text = html.unescape(html.unescape(text)).strip()
    return regex.sub(r"\s+", " ", text).strip().lower()


class ReferenceTokenizer:
    def __init__(self, bpe_path: str | Path = VOCAB_FILE, limit: int = CLIP_MERGES) -> None:
        merges = read_merges(bpe_path, limit)
        self.byte_symbol = bytes_to_unicode()
        symbols = list(self.byte_symbol.values())
        vocab = symbols + [s + "</w>" for s in symbols] + ["".join(m) for m in merges] + [START, END]
        self.ids = {token: index for index, token in enumerate(vocab)}
        self.rank = {merge: index for index, merge in enumerate(merges)}
        self.bpe = cache(self._bpe)

    def _bpe(self, word: str) -> tuple[str, ...]:
        symbols = [*word[:-1], word[-1] + "</w>"]
        while len(symbols) > 1:
            pairs = set(itertools.pairwise(symbols))
            best = min(pairs, key=lambda pair: self.rank.get(pair, float("inf")))
            if best not in self.rank:
                break
            merged, i = [], 0
            while i < len(symbols):
                if i + 1 < len(symbols) and (symbols[i], symbols[i + 1]) == best:
                    merged.append(symbols[i] + symbols[i + 1])
                    i += 2
                else:
                    merged.append(symbols[i])
                    i += 1
            symbols = merged
        return tuple(symbols)

    def encode(self, text: str, use_ftfy: bool = True) -> list[int]:
        ids = []
        for word in PATTERN.findall(clean(text, use_ftfy)):
            if word in (START, END):
                ids.append(self.ids[word])
                continue
            chars = "".join(self.byte_symbol[b] for b in word.encode("utf-8"))
            ids += [self.ids[s] for s in self.bpe(chars)]
        return ids

    def tokenize(self, text: str, context_length: int = 77, use_ftfy: bool = True) -> list[int]:
        """clip.tokenize(text, context_length, truncate=True)[0] as a list (zero-padded)."""
        ids = [self.ids[START], *self.encode(text, use_ftfy), self.ids[END]]
        if len(ids) > context_length:
            ids = ids[:context_length]
            ids[-1] = self.ids[END]
        return ids + [0] * (context_length - len(ids))
