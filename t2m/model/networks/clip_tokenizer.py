"""OpenAI CLIP's tokenizer as a `tokenizers` tokenizer (the service tokenizes with the `tokenizers` library only).

Target: OpenAI's ``clip.tokenize(text, context_length=77, truncate=True)``. Its rules, rebuilt here from the
merges list shipped in ``clip_data/`` (OpenAI's ``bpe_simple_vocab_16e6.txt.gz``, MIT):

1. clean the text: ftfy's ``fix_text``, ``html.unescape`` twice, whitespace runs -> one space, strip, Python's
   ``lower()``;
2. split into words with OpenAI's pattern (``'s|'t|'re|'ve|'m|'ll|'d|[\\p{L}]+|[\\p{N}]|[^\\s\\p{L}\\p{N}]+``);
   a literal ``<|startoftext|>`` / ``<|endoftext|>`` is its special token;
3. byte-level BPE with ``</w>`` marking each word's end: 256 byte symbols, the same with ``</w>``, the first
   48,894 merges, then ``<|startoftext|>`` = 49406 and ``<|endoftext|>`` = 49407;
4. ``[49406] + ids + [49407]``, cut to 77 with the end token kept last, zero padding to 77. Here the padding
   stops at the batch's longest text: the text tower's attention is causal, so the end token's features do not
   depend on what follows it (tests check ours at both lengths), and a batch of short captions runs ~4x faster.

Step 1 is a normaliser chain here. ftfy cannot run inside a tokenizer.json, so its deterministic character fixes are
reproduced (C1 controls read as Windows-1252, Latin ligatures, full/half-width forms, curly quotes, ANSI escapes
and invisible control characters removed, NFC), as are the HTML entities people paste (``&amp; &lt; &gt; &quot;
&apos; &#39; &nbsp;`` and the typographic quotes/dashes/ellipsis), unescaped twice, and Python's final-sigma rule of
``lower()`` (a word-final capital sigma becomes ς, where a plain per-character lowercase gives σ). Not reproduced:
ftfy's mojibake repair (``cafÃ©`` stays as it is), other HTML entities, entities without a semicolon and entities
nested more than twice; a special-token literal glued after punctuation (``!<|endoftext|>``, which OpenAI's
pattern reads as punctuation). Plain sentences are unaffected; tests/model/test_clip_tokenizer.py checks the
rules on tricky strings and the clip suite compares with OpenAI's and open_clip's tokenizers.
"""
from __future__ import annotations

import gzip
import unicodedata
from pathlib import Path

VOCAB_FILE = Path(__file__).parent / "clip_data" / "bpe_simple_vocab_16e6.txt.gz"
VOCAB_SHA256 = "924691ac288e54409236115652ad4aa250f48203de50a9e4722a6ecd48d6804a"
CONTEXT_LENGTH = 77
CLIP_MERGES = 49152 - 256 - 2  # OpenAI reads merges[1 : 49152 - 256 - 2 + 1] of the file
START, END = "<|startoftext|>", "<|endoftext|>"
VOCAB_SIZE = 2 * 256 + CLIP_MERGES + 2  # 49408
WORD_PATTERN = r"""'s|'t|'re|'ve|'m|'ll|'d|[\p{L}]+|[\p{N}]|[^\s\p{L}\p{N}]+"""

# html.unescape, for the entities people paste into captions
HTML_ENTITIES = {
    "&quot;": '"', "&#34;": '"', "&apos;": "'", "&#39;": "'", "&#039;": "'", "&#x27;": "'", "&lt;": "<", "&gt;": ">",
    "&nbsp;": "\xa0", "&lsquo;": "\u2018", "&rsquo;": "\u2019", "&ldquo;": "\u201c", "&rdquo;": "\u201d",
    "&ndash;": "\u2013", "&mdash;": "\u2014", "&hellip;": "\u2026",
    "&amp;": "&",  # last: one pass of html.unescape turns "&amp;lt;" into "&lt;", not "<"
}
# ftfy's fix_latin_ligatures table (Latin ligatures and legacy digraphs)
LATIN_LIGATURES = {
    "Ĳ": "IJ", "ĳ": "ij", "ŉ": "\u02bcn", "Ǳ": "DZ", "ǲ": "Dz", "ǳ": "dz", "Ǆ": "DŽ", "ǅ": "Dž", "ǆ": "dž",
    "Ǉ": "LJ", "ǈ": "Lj", "ǉ": "lj", "Ǌ": "NJ", "ǋ": "Nj", "ǌ": "nj",
    "ﬀ": "ff", "ﬁ": "fi", "ﬂ": "fl", "ﬃ": "ffi", "ﬄ": "ffl", "ﬅ": "ſt", "ﬆ": "st",
}
SINGLE_QUOTES = "[\\x{02BC}\\x{2018}-\\x{201B}]"  # ftfy's uncurl_quotes
DOUBLE_QUOTES = "[\\x{201C}-\\x{201F}]"
ANSI_ESCAPE = "\\x1b\\[[0-9;]*[a-zA-Z]"
# ftfy's remove_control_chars: C0 controls except tab, LF, FF, CR; DEL; deprecated format controls; BOM; U+FFF9-FFFC
INVISIBLE_CONTROLS = "[\\x00-\\x08\\x0b\\x0e-\\x1f\\x7f\\x{206A}-\\x{206F}\\x{FEFF}\\x{FFF9}-\\x{FFFC}]"
# the White_Space characters, which is what OpenAI's \s (the `regex` module) matches
WHITESPACE_RUN = ("[\\t\\n\\x0b\\x0c\\r \\x{85}\\x{A0}\\x{1680}\\x{2000}-\\x{200A}\\x{2028}\\x{2029}\\x{202F}\\x{205F}"
                  "\\x{3000}]+")
# Python's lower() maps a capital sigma to final ς after a cased letter (case-ignorables between) when no cased
# letter follows (case-ignorables between): Unicode's Final_Sigma condition.
FINAL_SIGMA = "(?<=\\p{Cased}\\p{Case_Ignorable}*)Σ(?!\\p{Case_Ignorable}*\\p{Cased})"


def bytes_to_unicode() -> dict[int, str]:
    """The reversible byte -> printable character table of byte-level BPE (printable bytes map to themselves)."""
    printable = [*range(ord("!"), ord("~") + 1), *range(ord("¡"), ord("¬") + 1), *range(ord("®"), ord("ÿ") + 1)]
    chars = printable[:]
    extra = 0
    for byte in range(256):
        if byte not in printable:
            printable.append(byte)
            chars.append(256 + extra)
            extra += 1
    return dict(zip(printable, (chr(c) for c in chars)))


def c1_controls_as_windows_1252() -> dict[str, str]:
    """ftfy's fix_c1_controls: U+0080-U+009F read as Windows-1252 bytes (the 5 undefined ones stay)."""
    table = {}
    for byte in range(0x80, 0xA0):
        try:
            table[chr(byte)] = bytes([byte]).decode("cp1252")
        except UnicodeDecodeError:
            continue
    return table


def width_forms() -> dict[str, str]:
    """ftfy's fix_character_width: fullwidth ASCII and halfwidth Katakana/Hangul (U+FF01-U+FFEF) to their NFKC
    forms, and the ideographic space to a space."""
    table = {"\u3000": " "}
    for code in range(0xFF01, 0xFFF0):
        char = chr(code)
        if (standard := unicodedata.normalize("NFKC", char)) != char:
            table[char] = standard
    return table


def read_merges(bpe_path: str | Path, limit: int = CLIP_MERGES) -> list[tuple[str, str]]:
    with gzip.open(bpe_path, "rt", encoding="utf-8") as handle:
        lines = handle.read().split("\n")
    merges = [tuple(line.split()) for line in lines[1 : limit + 1] if line.strip()]
    for index, merge in enumerate(merges):
        if len(merge) != 2:
            raise ValueError(f"{bpe_path}: line {index + 2} is not a merge of two symbols: {' '.join(merge)!r}")
    return merges  # type: ignore[return-value]


def openai_text_cleaning():
    """The normaliser chain of step 1 (see the module docstring for what it covers)."""
    from tokenizers import Regex, normalizers

    def replace_each(table: dict[str, str]) -> list:
        return [normalizers.Replace(old, new) for old, new in table.items()]

    html = replace_each(HTML_ENTITIES)
    ftfy_fixes = [
        *replace_each(c1_controls_as_windows_1252()),
        *replace_each(LATIN_LIGATURES),
        *replace_each(width_forms()),
        normalizers.Replace(Regex(SINGLE_QUOTES), "'"),
        normalizers.Replace(Regex(DOUBLE_QUOTES), '"'),
        normalizers.Replace(Regex(ANSI_ESCAPE), ""),
        normalizers.Replace(Regex(INVISIBLE_CONTROLS), ""),
        normalizers.NFC(),
    ]
    return normalizers.Sequence([
        *html, *html,  # html.unescape(html.unescape(text)); before ftfy's fixes so that &rsquo; is uncurled too
        *ftfy_fixes,
        normalizers.Replace(Regex(WHITESPACE_RUN), " "),
        normalizers.Strip(),
        normalizers.Replace(Regex(FINAL_SIGMA), "ς"),
        normalizers.Lowercase(),
    ])


def build_clip_tokenizer(bpe_path: str | Path | None = None, context_length: int = CONTEXT_LENGTH):
    """A `tokenizers.Tokenizer` that gives OpenAI's ``clip.tokenize(text, context_length, truncate=True)`` ids
    (and an attention mask), padded to the batch's longest, for the merges file ``bpe_path`` (default: OpenAI's,
    shipped in clip_data/)."""
    from tokenizers import AddedToken, Regex, Tokenizer, decoders, models, pre_tokenizers, processors

    merges = read_merges(bpe_path or VOCAB_FILE)
    symbols = list(bytes_to_unicode().values())
    vocab_list = symbols + [s + "</w>" for s in symbols] + ["".join(m) for m in merges] + [START, END]
    vocab = {token: index for index, token in enumerate(vocab_list)}
    tokenizer = Tokenizer(models.BPE(vocab=vocab, merges=merges, end_of_word_suffix="</w>", fuse_unk=False))
    tokenizer.normalizer = openai_text_cleaning()
    tokenizer.pre_tokenizer = pre_tokenizers.Sequence([
        pre_tokenizers.Split(Regex(WORD_PATTERN), behavior="removed", invert=True),
        pre_tokenizers.ByteLevel(add_prefix_space=False, use_regex=False),
    ])
    tokenizer.decoder = decoders.ByteLevel()
    # normalized=True: matched in the cleaned, lower-cased text, as OpenAI's pattern matches them after lower()
    tokenizer.add_special_tokens([AddedToken(token, special=True, normalized=True) for token in (START, END)])
    tokenizer.post_processor = processors.TemplateProcessing(
        single=f"{START} $A {END}", special_tokens=[(START, vocab[START]), (END, vocab[END])]
    )
    tokenizer.enable_truncation(max_length=context_length)  # the end token stays last
    tokenizer.enable_padding(pad_id=0, pad_token=vocab_list[0])  # with id 0 as OpenAI, to the batch's longest text
    return tokenizer


def save_clip_tokenizer(path: str | Path, context_length: int = CONTEXT_LENGTH,
                        bpe_path: str | Path | None = None) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    build_clip_tokenizer(bpe_path, context_length).save(str(path))
    return path
