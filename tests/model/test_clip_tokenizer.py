"""OpenAI CLIP's tokenizer as a tokenizer.json, against OpenAI's rules written out in Python
(tests/model/clip_reference_tokenizer.py) on tricky strings: cleaning (ftfy's fixes, HTML entities, whitespace,
Python's lower() with its final sigma), contractions, digits, special-token literals, truncation to 77 with the
end token last, zero padding (to the batch's longest). The clip suite (test_clip_reference.py) compares with
OpenAI's and open_clip's code."""
from __future__ import annotations

import gzip
import hashlib

import pytest

from t2m.model.networks.clip_tokenizer import (
    VOCAB_FILE,
    VOCAB_SHA256,
    VOCAB_SIZE,
    build_clip_tokenizer,
    bytes_to_unicode,
    save_clip_tokenizer,
)
from tests.model.clip_reference_tokenizer import ReferenceTokenizer, have_ftfy

START_ID, END_ID = 49406, 49407


def ids77(encoding) -> list[int]:
    """clip.tokenize's row: the ids zero-padded to 77 (ours pad only to the batch's longest)."""
    return encoding.ids + [0] * (77 - len(encoding.ids))

# strings that ftfy.fix_text leaves as they are (OpenAI's html.unescape, whitespace and lower() still apply)
PLAIN = [
    "a person walks forward",
    "  A PERSON\twalks\n\nforward!!  ",
    "IT'S a man's hat; they're here, we'll go, I'd say you've won, I'm done, don't",
    "walk 123 steps, 4.5 m in 2.0s (ok?) -- #1 @home 50%",
    "café crème, naïve façade, Ærø, São Paulo, Zürich, Ångström",
    "ΟΔΥΣΣΕΥΣ walks; ΑΣ' ΣΑ; ΤΕΛΟΣ. 'ΣΑΣ' σΣ",  # word-final capital sigma: Python's lower() gives ς
    "a runner 🏃‍♂️ runs, 👍🏽 then ❤️",
    "日本語のテキスト、한국어 텍스트, русский текст, עברית, العربية",
    "rock &amp; roll, he said &quot;hi&quot;, x&nbsp;y, it&#39;s, 3 &lt; 4",
    "<b>&amp;amp;</b> has a '<', so ftfy leaves the entities to html.unescape",
    "zero\u200bwidth joiner\u200d and soft\u00adhyphen",
    "a\u2028b\u3000c\u00a0d\u2009e",
    "a <|endoftext|> b <|startoftext|> c",
    "x <|ENDOFTEXT|> y, abc<|endoftext|>def",
    "İstanbul, ß straße STRASSE",
    "",
    "   \t\n ",
    "word " * 80,  # 80 words: cut to 75 + start + end
    "antidisestablishmentarianism " * 30,
    "a.b,c!d?e:f;g'h\"i(j)k[l]m{n}o<p>q/r\\s|t`u~v@w#x$y%z^&*-_=+",
]
# input -> what ftfy.fix_text makes of it (checked against ftfy itself where ftfy is installed)
FTFY_FIXED = {
    "cafe\u0301 au lait": "café au lait",  # NFC
    "a person\u2019s arm, \u2018single\u2019 \u201cdouble\u201d \u201equote\u201f":
        "a person's arm, 'single' \"double\" \"quote\"",
    "&rsquo;s and &amp;lt;tag&amp;gt;": "'s and <tag>",
    "ﬁnally ﬂows ﬀ ﬃ ﬄ ﬆ": "finally flows ff ffi ffl st",
    "ǅemal ĳs ŉ": "Džemal ijs 'n",
    "ＦＵＬＬ\u3000ｗｉｄｔｈ ｶﾞｷﾞ Ａ＆Ｂ": "FULL width ガギ A&B",
    "ctrl\x01char\x7f tab\x0bvt bom\ufeff": "ctrlchar tabvt bom",
    "\x1b[31mred\x1b[0m text": "red text",
    "c1 \x85 \x93q\x94": "c1 … \"q\"",
}
# where this tokenizer.json and OpenAI's tokenizer part ways (documented in clip_tokenizer's docstring):
# case -> (input, what ftfy.fix_text makes of it)
KNOWN_DIFFERENCES = {
    "special literal after punctuation": ("wait!<|endoftext|>", "wait!<|endoftext|>"),
    "entity without semicolon": ("this&not that", "this&not that"),  # html.unescape reads "this¬ that"
    "mojibake": ("cafÃ© au lait", "café au lait"),
}


@pytest.fixture(scope="module")
def tokenizer():
    return build_clip_tokenizer()


@pytest.fixture(scope="module")
def reference():
    return ReferenceTokenizer()


def test_vocabulary_file_is_openais(tokenizer):
    data = VOCAB_FILE.read_bytes()
    assert hashlib.sha256(data).hexdigest() == VOCAB_SHA256 and len(data) == 1_356_917
    assert (VOCAB_FILE.parent / "LICENSE").read_text().startswith("MIT License\n\nCopyright (c) 2021 OpenAI")
    assert tokenizer.get_vocab_size() == VOCAB_SIZE == 49408
    assert tokenizer.token_to_id("<|startoftext|>") == START_ID and tokenizer.token_to_id("<|endoftext|>") == END_ID
    assert tokenizer.token_to_id("!") == 0 and tokenizer.token_to_id("in") == 512  # first byte symbol, first merge


@pytest.mark.parametrize("index", range(len(PLAIN)))
def test_plain_strings_tokenize_as_openai(tokenizer, reference, index):
    text = PLAIN[index]
    encoding = tokenizer.encode(text)
    expected = reference.tokenize(text, use_ftfy=have_ftfy())
    assert ids77(encoding) == expected, tokenizer.normalizer.normalize_str(text)
    real = min(77, len(reference.encode(text, use_ftfy=have_ftfy())) + 2)  # id 0 is also "!": count, don't look
    assert len(encoding.ids) == real and encoding.attention_mask == [1] * real


@pytest.mark.parametrize("text", sorted(FTFY_FIXED))
def test_ftfy_fixes_are_reproduced(tokenizer, reference, text):
    if have_ftfy():
        import ftfy

        assert ftfy.fix_text(text) == FTFY_FIXED[text]
        assert ids77(tokenizer.encode(text)) == reference.tokenize(text)
    assert ids77(tokenizer.encode(text)) == reference.tokenize(FTFY_FIXED[text], use_ftfy=False)


@pytest.mark.parametrize("case", sorted(KNOWN_DIFFERENCES))
@pytest.mark.xfail(strict=True, reason="documented difference from OpenAI's tokenizer")
def test_known_differences(tokenizer, reference, case):
    text, fixed = KNOWN_DIFFERENCES[case]
    if have_ftfy():
        import ftfy

        assert ftfy.fix_text(text) == fixed
    assert ids77(tokenizer.encode(text)) == reference.tokenize(fixed, use_ftfy=False)


def test_truncation_keeps_the_end_token_last_and_padding_is_zero(tokenizer):
    long, short, empty = tokenizer.encode_batch(["walk " * 200, "bow", ""])
    assert len(long.ids) == 77 and long.ids[0] == START_ID and long.ids[-1] == END_ID
    assert long.ids[1:-1] == [long.ids[1]] * 75 and long.attention_mask == [1] * 77
    assert short.ids == [START_ID, tokenizer.token_to_id("bow</w>"), END_ID] + [0] * 74  # padded to the longest
    assert short.attention_mask == [1] * 3 + [0] * 74 and empty.ids[:3] == [START_ID, END_ID, 0]
    assert [len(e.ids) for e in tokenizer.encode_batch(["bow", "a person walks"])] == [5, 5]


def test_saved_file_is_what_the_service_loads(tmp_path, tokenizer):
    from t2m.runtime.text import load_tokenizer

    path = save_clip_tokenizer(tmp_path / "tokenizer.json")
    served = load_tokenizer(path, max_length=77)
    texts = [PLAIN[1], PLAIN[5], PLAIN[17], *FTFY_FIXED]
    assert [e.ids for e in served.encode_batch(texts)] == [e.ids for e in tokenizer.encode_batch(texts)]
    assert {len(e.ids) for e in served.encode_batch(texts)} == {77}  # PLAIN[17] is cut to 77
    longest = max(len(tokenizer.encode(t).ids) for t in texts[:2])
    assert {len(e.ids) for e in served.encode_batch(texts[:2])} == {longest}


def test_merges_file_format_and_word_end_marker(tmp_path):
    """A small merges file in the release's format: ids follow the vocabulary's construction."""
    merges = ["h e", "l l", "he ll", "hell o</w>", "w a", "wa l", "wal k", "walk s</w>"]
    bpe = tmp_path / "bpe_simple_vocab_16e6.txt.gz"
    with gzip.open(bpe, "wt", encoding="utf-8") as handle:
        handle.write("#version: 0.2\n" + "\n".join(merges) + "\n")
    small = build_clip_tokenizer(bpe, context_length=8)
    byte_id = {ch: i for i, ch in enumerate(bytes_to_unicode().values())}
    hello, walks = 512 + 3, 512 + 7  # after 256 symbols + 256 word-end symbols, in merge order
    start, end = 512 + len(merges), 512 + len(merges) + 1
    encoding = small.encode("  HELLO   walks!")
    assert encoding.ids == [start, hello, walks, 256 + byte_id["!"], end]
    assert small.encode("walk's 42").tokens[1:6] == ["wal", "k</w>", "'", "s</w>", "4</w>"]
    reference = ReferenceTokenizer(bpe, limit=len(merges))
    for text in ("  HELLO   walks!", "walk's 42", "hellohello walkswalks"):
        ids = small.encode(text).ids
        assert ids + [0] * (8 - len(ids)) == reference.tokenize(text, context_length=8, use_ftfy=False)
