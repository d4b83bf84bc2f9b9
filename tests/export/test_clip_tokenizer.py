"""CLIP's BPE rebuilt as a tokenizers tokenizer.json, on a small merges file in the release's format."""
from __future__ import annotations

import gzip

from t2m.export.clip_tokenizer import build_clip_tokenizer, bytes_to_unicode

MERGES = ["h e", "l l", "he ll", "hell o</w>", "w a", "wa l", "wal k", "walk s</w>"]


def test_clip_tokenizer_matches_open_clip_rules(tmp_path):
    bpe = tmp_path / "bpe_simple_vocab_16e6.txt.gz"
    with gzip.open(bpe, "wt", encoding="utf-8") as handle:
        handle.write("#version: 0.2\n" + "\n".join(MERGES) + "\n")
    tokenizer = build_clip_tokenizer(bpe, context_length=8)
    byte_id = {ch: i for i, ch in enumerate(bytes_to_unicode().values())}
    hello, walks = 512 + 3, 512 + 7  # after 256 symbols + 256 word-end symbols, in merge order
    start, end = 512 + len(MERGES), 512 + len(MERGES) + 1
    encoding = tokenizer.encode("  HELLO   walks!")
    assert encoding.ids == [start, hello, walks, 256 + byte_id["!"], end, 0, 0, 0]  # lower-cased, "!" a word of its own
    assert encoding.attention_mask == [1, 1, 1, 1, 1, 0, 0, 0]
    long = tokenizer.encode("hello " * 20)
    assert len(long.ids) == 8 and long.ids[0] == start and long.ids[-1] == end  # truncated, end token kept last
    assert tokenizer.encode("walk's 42").tokens[1:6] == ["wal", "k</w>", "'", "s</w>", "4</w>"]
    saved = tmp_path / "tokenizer.json"
    tokenizer.save(str(saved))
    from tokenizers import Tokenizer

    assert Tokenizer.from_file(str(saved)).encode("hello walks").ids == encoding.ids[:3] + [end, 0, 0, 0, 0]
