"""t2m.model.data.captions: several distinct, deterministic, natural captions per label pair; mirroring; the text
format."""
from __future__ import annotations

import re

import pytest

from t2m.model.data.captions import (
    CONTENT_PHRASES,
    HANDED_PHRASES,
    STYLE_PHRASES,
    format_caption_line,
    make_captions,
    mirror_caption,
    mirror_label,
    parse_caption_line,
    pos_tag,
)

# both datasets' labels (docs/data.md); dataset-1's `dance-long` has no clip but is a label
DATASET_1_CONTENTS = ["walk", "run", "dash", "walk-back", "walk-left", "walk-right", "bow", "bye", "byebye", "guide",
                      "respond", "call", "punch", "kick", "slash", "dance-long", "dance-short"]
DATASET_1_STYLES = ["normal", "happy", "sad", "angry", "proud", "not-confident", "masculinity", "feminine",
                    "childish", "old", "tired", "active", "musical", "giant", "chimpira"]
DATASET_2_CONTENTS = ["walk", "walk-turn-left", "walk-turn-right", "run", "wave-both-hands", "wave-left-hand",
                      "wave-right-hand", "raise-up-both-hands", "raise-up-left-hand", "raise-up-right-hand"]
DATASET_2_STYLES = ["active", "elderly", "exhausted", "feminine", "masculine", "normal", "youthful"]
PAIRS = [(c, s) for c in DATASET_1_CONTENTS for s in DATASET_1_STYLES] + \
        [(c, s) for c in DATASET_2_CONTENTS for s in DATASET_2_STYLES]


def test_every_label_pair_gets_six_distinct_captions() -> None:
    for content, style in PAIRS:
        captions = make_captions(content, style, f"dataset_{content}_{style}_001")
        assert len(captions) == 6 == len(set(captions)), (content, style, captions)
        assert all(re.fullmatch(r"[a-z][a-z ,\-]+", c) for c in captions), captions


def test_captions_vary_in_structure_not_only_in_synonyms() -> None:
    captions = make_captions("wave-left-hand", "elderly", "dataset-2_wave-left-hand_elderly_003")
    openings = {" ".join(c.split()[:2]) for c in captions}
    assert len(openings) >= 3
    assert all("left" in c and "right" not in c for c in captions)


def test_captions_are_deterministic_per_clip_and_differ_between_clips() -> None:
    first = make_captions("walk", "tired", "dataset-1_walk_tired_001")
    assert first == make_captions("walk", "tired", "dataset-1_walk_tired_001")
    assert first != make_captions("walk", "tired", "dataset-1_walk_tired_002")


def test_style_and_content_show_up_in_the_words() -> None:
    captions = " ".join(make_captions("run", "happy", "x"))
    assert re.search(r"\b(run|runs|running|jog|jogs|jogging)\b", captions)
    assert re.search(r"happ|cheer|joy", captions)
    normal = make_captions("bow", "normal", "y")
    assert any(c in ("a person bows", "someone bows", "the person bows", "a person bows politely") or "bow" in c
               for c in normal)


def test_style_phrases_never_say_left_or_right() -> None:
    # otherwise mirroring a caption would flip words that are not about sides
    for phrases in STYLE_PHRASES.values():
        for text in phrases.adjectives + phrases.manners + phrases.states:
            assert not re.search(r"\b(left|right)\b", text), text


def test_mirror_caption_swaps_whole_words_and_keeps_case() -> None:
    assert mirror_caption("a person waves the left hand then turns right") == \
        "a person waves the right hand then turns left"
    assert mirror_caption("Left foot, RIGHT hand; bright lefty") == "Right foot, LEFT hand; bright lefty"


@pytest.mark.parametrize("label, mirrored", [("walk-left", "walk-right"), ("walk-turn-right", "walk-turn-left"),
                                             ("wave-left-hand", "wave-right-hand"),
                                             ("raise-up-right-hand", "raise-up-left-hand"), ("walk", "walk"),
                                             ("wave-both-hands", "wave-both-hands")])
def test_mirror_label(label: str, mirrored: str) -> None:
    assert mirror_label(label) == mirrored


def test_mirrored_label_captions_are_the_mirror_of_the_words() -> None:
    for content in CONTENT_PHRASES:
        mirrored = mirror_label(content)
        assert [mirror_caption(p) for p in CONTENT_PHRASES[content]] == list(CONTENT_PHRASES[mirrored])


def test_handed_gestures_name_the_hand_when_known() -> None:
    for content in HANDED_PHRASES:
        captions = make_captions(content, "normal", f"{content}_1", side="right")
        assert sum("right hand" in c for c in captions) >= 3
        assert not any("left" in c for c in captions)
    with pytest.raises(ValueError, match="side must be"):
        make_captions("bye", "normal", "x", side="up")


def test_unknown_labels_are_rejected_with_the_known_ones() -> None:
    with pytest.raises(ValueError, match=r"unknown content label 'fly'.*walk"):
        make_captions("fly", "normal", "x")
    with pytest.raises(ValueError, match="unknown style label 'sleepy'"):
        make_captions("walk", "sleepy", "x")


def test_humanml3d_line_format_and_pos_tags() -> None:
    line = format_caption_line("an elderly person waves the left hand")
    assert line == ("an elderly person waves the left hand#an/DET elderly/ADJ person/NOUN wave/VERB the/DET "
                    "left/ADJ hand/NOUN#0.0#0.0")
    assert parse_caption_line(line) == "an elderly person waves the left hand"
    assert pos_tag("someone walks and takes a right turn") == [
        ("someone", "PRON"), ("walk", "VERB"), ("and", "CCONJ"), ("take", "VERB"), ("a", "DET"),
        ("right", "ADJ"), ("turn", "NOUN")]
    assert pos_tag("a person is running happily")[3:] == [("run", "VERB"), ("happily", "ADV")]
    with pytest.raises(ValueError, match="must not contain"):
        format_caption_line("a # b")


def test_every_template_word_is_in_the_lexicon_or_an_adverb() -> None:
    from t2m.model.data import captions
    combos = [(c, "tired") for c in CONTENT_PHRASES] + [("walk-turn-left", s) for s in STYLE_PHRASES] + \
        [(c, "normal", "left") for c in HANDED_PHRASES]  # every phrase list once; sentences are their products
    for content, style, *side in combos:
        for group in captions._candidates(content, style, *side):
            for sentence in group:
                for word in re.findall(r"[a-z]+", sentence):
                    assert (word in captions._LEXICON or word in captions._VERB_LEMMAS
                            or word in ("left", "right") or word.endswith("ly")), (word, sentence)
