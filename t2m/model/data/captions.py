"""Templated English captions for categorically labelled motion clips (Bandai-Namco: content x style).

The Bandai-Namco clips carry only two labels (what is done, e.g. `wave-left-hand`, and how, e.g. `elderly`), while
text-to-motion models learn from free sentences. So each clip gets several sentences built from varied frames
("an elderly person waves with the left hand", "someone walks forward in a tired way"), with synonyms for both the
action and the style, picked deterministically from the clip id so that a rebuild gives the same text. The
captions are templated, not written by people; the README says so.

Each caption is stored in HumanML3D's texts/*.txt line format `caption#tok/POS tok/POS ...#0.0#0.0`. The POS
part comes from a small lexicon of the words these templates use (universal POS tags as HumanML3D's spaCy output:
DET NOUN VERB ADJ ADV ADP PRON CCONJ PART AUX), with verbs lemmatised; unknown words fall back to suffix rules
(-ly ADV, -ing VERB, otherwise NOUN). Good enough for an evaluator's word features; not a general tagger.
"""
from __future__ import annotations

import hashlib
import random
import re
from dataclasses import dataclass

__all__ = [
    "CONTENT_PHRASES",
    "HANDED_PHRASES",
    "STYLE_PHRASES",
    "caption_key",
    "format_caption_line",
    "make_captions",
    "mirror_caption",
    "mirror_label",
    "parse_caption_line",
    "pos_tag",
]

# --- what is done: verb phrases in the third person singular present -------------------------------------------
# Checked on the data: walk-left/right clips walk toward the left/right of where the body first faces (about
# 20-30 degrees), walk-turn-left/right clips turn about 90 degrees, walk-back clips step backwards, `bye` and
# `guide` mostly use one hand, `byebye` both, `respond` raises a hand, `call` brings the hands up to call out.
CONTENT_PHRASES: dict[str, tuple[str, ...]] = {
    "walk": ("walks forward", "walks straight ahead", "walks forward a few steps", "takes a walk forward",
             "walks ahead in a straight line", "moves forward on foot", "walks on ahead"),
    "run": ("runs forward", "runs straight ahead", "jogs forward", "runs ahead", "runs along in a straight line",
            "jogs ahead", "goes for a run forward", "runs on ahead"),
    "dash": ("dashes forward", "sprints forward", "runs forward at full speed", "dashes ahead", "races ahead",
             "sprints off at top speed", "races forward at full tilt"),
    "walk-back": ("walks backward", "walks backwards", "steps backward", "walks back without turning around",
                  "backs up a few steps", "takes a few steps backward", "walks backward while facing forward",
                  "moves backward on foot", "backs away step after step"),
    "walk-left": ("walks to the left", "walks toward the left", "walks forward and to the left",
                  "walks diagonally to the left", "walks ahead bearing to the left", "walks off toward the left"),
    "walk-right": ("walks to the right", "walks toward the right", "walks forward and to the right",
                   "walks diagonally to the right", "walks ahead bearing to the right", "walks off toward the right"),
    "walk-turn-left": ("walks and turns left", "walks forward then turns to the left",
                       "makes a left turn while walking", "walks and takes a left turn", "turns left while walking",
                       "walks and changes direction to the left", "walks and curves to the left",
                       "walks then swings to the left"),
    "walk-turn-right": ("walks and turns right", "walks forward then turns to the right",
                        "makes a right turn while walking", "walks and takes a right turn", "turns right while walking",
                        "walks and changes direction to the right", "walks and curves to the right",
                        "walks then swings to the right"),
    "bow": ("bows", "bows politely", "gives a bow", "bends forward in a bow", "bows deeply", "bows at the waist",
            "makes a deep bow", "leans forward to bow", "bows with the head lowered", "bends at the waist to bow"),
    "bye": ("waves goodbye", "says goodbye with a wave", "waves a hand to say goodbye", "waves bye",
            "waves farewell", "waves to someone leaving"),
    "byebye": ("waves goodbye with both hands", "waves both hands to say goodbye", "says bye bye with both hands",
               "waves bye bye", "waves farewell with both hands"),
    "guide": ("gestures to show the way", "guides someone with a hand gesture", "points the way with a hand",
              "shows someone where to go", "directs someone with a sweep of the hand"),
    "respond": ("raises a hand to respond", "responds by raising a hand", "raises a hand in reply",
                "answers by putting a hand up"),
    "call": ("calls out to someone", "calls out with hands near the mouth", "shouts to call someone",
             "calls to someone far away"),
    "punch": ("punches", "throws punches", "punches forward", "throws a few punches", "boxes with both fists"),
    "kick": ("kicks", "kicks forward", "throws a kick", "kicks with a leg", "lifts a leg and kicks",
             "swings a leg up to kick", "kicks with the foot", "does a spinning kick", "performs martial arts kicks",
             "kicks several times"),
    "slash": ("slashes with a sword", "swings a sword", "makes slashing moves with a sword", "slashes the air"),
    "dance-long": ("dances", "performs a long dance", "dances for a while", "does a dance routine"),
    "dance-short": ("dances", "performs a dance", "does a dance", "dances with big moves"),
    "wave-both-hands": ("waves both hands", "waves with both hands", "waves both arms", "waves both hands in the air",
                        "waves hello with both hands", "gives a big wave with both arms"),
    "wave-left-hand": ("waves the left hand", "waves with the left hand", "waves using the left hand",
                       "waves the left arm", "waves hello with the left hand", "gives a wave with the left hand"),
    "wave-right-hand": ("waves the right hand", "waves with the right hand", "waves using the right hand",
                        "waves the right arm", "waves hello with the right hand", "gives a wave with the right hand"),
    "raise-up-both-hands": ("raises both hands", "raises both arms up", "puts both hands up", "lifts both hands up",
                            "stretches both arms upward", "reaches up with both hands", "raises both arms overhead"),
    "raise-up-left-hand": ("raises the left hand", "raises the left arm up", "puts the left hand up",
                           "lifts the left hand up", "reaches up with the left hand", "stretches the left arm upward",
                           "raises the left arm overhead"),
    "raise-up-right-hand": ("raises the right hand", "raises the right arm up", "puts the right hand up",
                            "lifts the right hand up", "reaches up with the right hand",
                            "stretches the right arm upward", "raises the right arm overhead"),
}


# One-handed gestures whose labels do not say which hand: when the builder sees which hand moved (`side`), these
# phrasings are added, so that the text of a mirrored clip (left/right swapped) stays true.
HANDED_PHRASES: dict[str, tuple[str, ...]] = {
    "bye": ("waves goodbye with the {side} hand", "waves the {side} hand to say goodbye",
            "says goodbye with a wave of the {side} hand"),
    "guide": ("gestures with the {side} hand to show the way", "points the way with the {side} hand",
              "guides someone with the {side} hand"),
    "respond": ("raises the {side} hand to respond", "responds by raising the {side} hand",
                "puts the {side} hand up in reply"),
    "call": ("calls out to someone with the {side} hand raised", "raises the {side} hand and calls out to someone"),
}


@dataclass(frozen=True)
class StylePhrases:
    """Ways to say a style: as an adjective on the subject, as a manner (adverbial), and as a state ("looking sad")."""

    adjectives: tuple[str, ...]
    manners: tuple[str, ...]
    states: tuple[str, ...]


# `normal` has no adjective: "a person walks forward"; its manners stay plain.
STYLE_PHRASES: dict[str, StylePhrases] = {
    "normal": StylePhrases((), ("in an ordinary way", "calmly", "in a relaxed way"), ()),
    "happy": StylePhrases(("happy", "cheerful", "joyful"), ("happily", "cheerfully", "in a happy way"),
                          ("looking happy", "in a cheerful mood")),
    "sad": StylePhrases(("sad", "gloomy", "sorrowful"), ("sadly", "gloomily", "in a sad way"),
                        ("looking sad", "looking downcast")),
    "angry": StylePhrases(("angry", "furious", "irritated"), ("angrily", "furiously", "in an angry way"),
                          ("looking angry", "in an angry mood")),
    "proud": StylePhrases(("proud", "haughty"), ("proudly", "in a proud way", "with a proud posture"),
                          ("looking proud", "with the chest puffed out")),
    "not-confident": StylePhrases(("timid", "insecure", "unconfident"),
                                  ("timidly", "hesitantly", "without confidence"),
                                  ("looking unsure", "lacking confidence")),
    "masculinity": StylePhrases(("masculine", "manly"), ("in a masculine way", "in a manly manner"),
                                ("with a masculine posture",)),
    "masculine": StylePhrases(("masculine", "manly"), ("in a masculine way", "in a manly manner"),
                              ("with a masculine posture",)),
    "feminine": StylePhrases(("feminine", "graceful"), ("in a feminine way", "gracefully", "in a feminine manner"),
                             ("with a feminine posture",)),
    "childish": StylePhrases(("childish", "childlike", "playful"), ("childishly", "like a child", "playfully"),
                             ("acting like a child",)),
    "old": StylePhrases(("old", "elderly", "aged"), ("like an old person", "in an elderly way", "slowly and stiffly"),
                        ("looking frail",)),
    "elderly": StylePhrases(("elderly", "old", "aged"), ("like an elderly person", "in an elderly way",
                                                         "slowly and stiffly"), ("looking frail",)),
    "tired": StylePhrases(("tired", "weary", "sleepy"), ("wearily", "in a tired way", "sluggishly"),
                          ("looking tired", "looking worn out")),
    "exhausted": StylePhrases(("exhausted", "worn-out", "very tired"), ("wearily", "in an exhausted way",
                                                                       "with barely any energy"),
                              ("looking exhausted", "out of breath")),
    "active": StylePhrases(("energetic", "lively", "active"), ("energetically", "in a lively way",
                                                              "with lots of energy"), ("full of energy",)),
    "musical": StylePhrases(("theatrical", "showy"), ("like in a musical", "theatrically", "in a theatrical way"),
                            ("as if on a stage",)),
    "giant": StylePhrases(("huge", "hulking", "heavy"), ("like a giant", "with heavy lumbering steps",
                                                      "in a heavy lumbering way"), ("moving like a giant",)),
    "chimpira": StylePhrases(("thuggish", "delinquent", "swaggering"), ("like a thug", "like a street punk",
                                                                       "with a swagger"), ("acting tough",)),
    "youthful": StylePhrases(("young", "youthful"), ("in a youthful way", "youthfully", "with youthful energy"),
                             ("full of youthful energy",)),
}

SUBJECTS = ("a person", "someone", "the person", "a man", "a woman")
_NOUNS_FOR_STYLE = {"masculinity": ("person", "man"), "masculine": ("person", "man"), "feminine": ("person", "woman")}
_PLAIN_SUBJECTS = ("a person", "someone", "the person")  # for sentences that do not name the style in the subject

# --- left / right --------------------------------------------------------------------------------------------------
_SIDE_WORD = re.compile(r"\b(left|right)\b", re.IGNORECASE)


def _swap_side(match: re.Match[str]) -> str:
    word = match.group(0)
    swapped = "right" if word.lower() == "left" else "left"
    if word.isupper():
        return swapped.upper()
    if word[0].isupper():
        return swapped.capitalize()
    return swapped


def mirror_caption(caption: str) -> str:
    """Swap the words 'left' and 'right' (whole words, case kept) - the text of a mirrored motion."""
    return _SIDE_WORD.sub(_swap_side, caption)


def mirror_label(content: str) -> str:
    """The content label of the mirrored clip: walk-left <-> walk-right, wave-left-hand <-> wave-right-hand, ..."""
    parts = content.split("-")
    return "-".join({"left": "right", "right": "left"}.get(p, p) for p in parts)


# --- sentence building ---------------------------------------------------------------------------------------------
def _article(word: str) -> str:
    return "an" if word[0] in "aeiou" else "a"


def _ing_form(lemma: str) -> str:
    if lemma.endswith("e") and not lemma.endswith("ee"):
        return lemma[:-1] + "ing"
    if lemma in _DOUBLE_FINAL:
        return lemma + lemma[-1] + "ing"
    return lemma + "ing"


def _gerund(verb_phrase: str) -> str:
    """'walks forward then turns left' -> 'walking forward then turning left' (the first verb and verbs after
    'and'/'then'; the templates use only verbs listed in _VERB_LEMMAS)."""
    words = verb_phrase.split(" ")
    for i, word in enumerate(words):
        lemma = _VERB_LEMMAS.get(word)
        if i == 0 and lemma is None:
            raise ValueError(f"no lemma for verb {word!r}; add it to captions._VERB_LEMMAS")
        if lemma is not None and (i == 0 or words[i - 1] in ("and", "then")):
            words[i] = _ing_form(lemma)
    return " ".join(words)


def _candidates(content: str, style: str, side: str | None = None) -> list[list[str]]:
    """All sentences for (content, style), grouped by sentence frame so picks can spread across frames."""
    if content not in CONTENT_PHRASES:
        raise ValueError(f"unknown content label {content!r}; known: {', '.join(sorted(CONTENT_PHRASES))}")
    if style not in STYLE_PHRASES:
        raise ValueError(f"unknown style label {style!r}; known: {', '.join(sorted(STYLE_PHRASES))}")
    if side not in (None, "left", "right"):
        raise ValueError(f"side must be 'left', 'right' or None, got {side!r}")
    actions = CONTENT_PHRASES[content]
    if side is not None and content in HANDED_PHRASES:  # the hand is known: say it in most sentences
        actions = tuple(p.format(side=side) for p in HANDED_PHRASES[content]) + actions[:1]
    phrases = STYLE_PHRASES[style]
    frames: list[list[str]] = []
    if phrases.adjectives:  # "an elderly person waves the left hand"
        nouns = _NOUNS_FOR_STYLE.get(style, ("person", "man", "woman"))
        frames.append([f"{_article(adj)} {adj} {noun} {act}" for adj in phrases.adjectives
                       for noun in nouns for act in actions])
    else:
        frames.append([f"{subject} {act}" for subject in SUBJECTS for act in actions])
    frames.append([f"{subject} {act} {manner}" for subject in _PLAIN_SUBJECTS for act in actions
                   for manner in phrases.manners])  # "someone walks forward in a tired way"
    if phrases.states:  # "a person walks forward, looking tired"
        frames.append([f"{subject} {act} while {state}" if state.startswith("looking")
                       else f"{subject} {act}, {state}"
                       for subject in _PLAIN_SUBJECTS for act in actions for state in phrases.states])
    frames.append([f"{subject} is {_gerund(act)} {manner}" for subject in _PLAIN_SUBJECTS for act in actions
                   for manner in phrases.manners])  # "the person is walking forward wearily"
    if phrases.adjectives:  # "someone who is tired walks forward"
        frames.append([f"{subject} who is {adj} {act}" for subject in ("a person", "someone")
                       for adj in phrases.adjectives for act in actions])
    return frames


def _seed(clip_id: str) -> int:
    return int.from_bytes(hashlib.sha256(clip_id.encode("utf-8")).digest()[:8], "big")


def make_captions(content: str, style: str, clip_id: str, count: int = 6, side: str | None = None) -> list[str]:
    """`count` distinct captions for one clip, the same for the same clip id on every machine and run.

    Frames are visited round-robin (in an order shuffled per clip) so the captions differ in structure, not only
    in a synonym. `side` ('left'/'right') names the hand of a one-handed gesture (HANDED_PHRASES) when known.
    """
    rng = random.Random(_seed(clip_id))
    frames = [list(group) for group in _candidates(content, style, side)]
    for group in frames:
        rng.shuffle(group)
    rng.shuffle(frames)
    chosen: list[str] = []
    while len(chosen) < count and any(frames):
        for group in frames:
            while group:
                sentence = group.pop()
                if sentence not in chosen:
                    chosen.append(sentence)
                    break
            if len(chosen) == count:
                break
    return chosen


# --- HumanML3D text line format ------------------------------------------------------------------------------------
_DOUBLE_FINAL = {"run", "jog", "step", "put"}
_VERB_LEMMAS = {
    "walks": "walk", "runs": "run", "jogs": "jog", "dashes": "dash", "sprints": "sprint", "takes": "take",
    "steps": "step", "bows": "bow", "gives": "give", "bends": "bend", "waves": "wave", "says": "say",
    "gestures": "gesture", "guides": "guide", "points": "point", "shows": "show", "raises": "raise",
    "responds": "respond", "answers": "answer", "calls": "call", "shouts": "shout", "punches": "punch",
    "throws": "throw", "kicks": "kick", "slashes": "slash", "swings": "swing", "makes": "make", "dances": "dance",
    "performs": "perform", "does": "do", "puts": "put", "lifts": "lift", "turns": "turn",
    "looking": "look", "acting": "act", "lacking": "lack", "moving": "move", "using": "use",
    "moves": "move", "backs": "back", "races": "race", "changes": "change", "curves": "curve", "leans": "lean",
    "reaches": "reach", "stretches": "stretch", "boxes": "box", "directs": "direct", "goes": "go",
    "facing": "face", "leaving": "leave", "bearing": "bear",
}
_BASE_VERBS = set(_VERB_LEMMAS.values()) | {"go"}
_VERB_LEMMAS.update({_ing_form(lemma): lemma for lemma in list(_BASE_VERBS)})
_VERB_LEMMAS.update({lemma: lemma for lemma in _BASE_VERBS - {"back"}})  # bare "back" is the adverb ("walks back")


_LEXICON = {
    **dict.fromkeys(("a", "an", "the", "both"), "DET"),
    **dict.fromkeys(("someone", "who"), "PRON"),
    **dict.fromkeys(("to", "with", "in", "like", "without", "near", "toward", "at", "for", "by", "of", "as", "on",
                     "out", "up", "around", "after", "off"), "ADP"),
    **dict.fromkeys(("while", "if"), "SCONJ"),
    **dict.fromkeys(("and",), "CCONJ"),
    **dict.fromkeys(("is",), "AUX"),
    **dict.fromkeys(("not",), "PART"),
    **dict.fromkeys(("forward", "ahead", "straight", "backward", "backwards", "back", "away", "far", "very",
                     "diagonally", "slowly", "stiffly", "where", "bye", "goodbye", "along", "upward", "overhead",
                     "hello", "farewell", "then"), "ADV"),
    **dict.fromkeys(("happy", "cheerful", "joyful", "sad", "gloomy", "sorrowful", "angry", "furious", "irritated",
                     "proud", "haughty", "timid", "insecure", "unconfident", "unsure", "masculine", "manly", "feminine",
                     "graceful", "childish", "childlike", "playful", "old", "elderly", "aged", "frail", "tired",
                     "weary", "sleepy", "exhausted", "worn", "energetic", "lively", "active", "theatrical", "showy",
                     "huge", "heavy", "thuggish", "delinquent", "swaggering", "young", "youthful", "ordinary",
                     "relaxed", "any", "full", "few", "long", "big", "lumbering", "downcast", "tough", "puffed", "no",
                     "short", "slashing", "hulking", "raised", "top", "deep", "lowered", "martial", "several",
                     "spinning"), "ADJ"),
    **dict.fromkeys(("person", "man", "woman", "hand", "hands", "arm", "arms", "leg", "walk", "way", "steps", "speed",
                     "turn", "bow", "wave", "gesture", "mouth", "punches", "kick", "sword", "air", "moves", "dance",
                     "routine", "manner", "posture", "chest", "energy", "confidence", "mood", "child", "thug", "street",
                     "punk", "swagger", "stage", "breath", "reply", "musical", "lots", "giant", "head", "waist", "tilt",
                     "fists", "times", "arts", "direction", "foot", "line", "sweep"), "NOUN"),
}
_SIDE_ADJ_NOUNS = {"hand", "arm", "leg", "turn", "side", "foot"}


def pos_tag(caption: str) -> list[tuple[str, str]]:
    """(lemma, POS) per word of a caption, lower case, punctuation dropped (HumanML3D's token format)."""
    words = re.findall(r"[a-z]+", caption.lower())
    tags: list[tuple[str, str]] = []
    for i, word in enumerate(words):
        following = words[i + 1] if i + 1 < len(words) else ""
        if word in ("left", "right"):  # "the left hand" (ADJ) vs "turns left" (ADV) vs "to the left" (NOUN)
            if following in _SIDE_ADJ_NOUNS:
                tags.append((word, "ADJ"))
            elif i > 0 and words[i - 1] == "the":
                tags.append((word, "NOUN"))
            else:
                tags.append((word, "ADV"))
        elif word in _VERB_LEMMAS:
            # "a walk", "a right turn", "throws punches": a word that is also a noun is one after a determiner,
            # an adjective or a verb; otherwise it is the verb (lemmatised: "waves" -> "wave").
            previous = tags[-1][1] if tags else ""
            if _LEXICON.get(word) == "NOUN" and previous in ("DET", "ADJ", "VERB"):
                tags.append((word, "NOUN"))
            else:
                tags.append((_VERB_LEMMAS[word], "VERB"))
        elif word in _LEXICON:
            tag = _LEXICON[word]
            tags.append((word, tag))
        elif word.endswith("ly"):
            tags.append((word, "ADV"))
        elif word.endswith("ing"):
            tags.append((word, "VERB"))
        else:
            tags.append((word, "NOUN"))
    return tags


def format_caption_line(caption: str) -> str:
    """HumanML3D texts/*.txt line: `caption#tok/POS ...#0.0#0.0` (0.0-0.0 = the caption covers the whole clip)."""
    if "#" in caption or "\n" in caption:
        raise ValueError(f"caption must not contain '#' or a newline: {caption!r}")
    tokens = " ".join(f"{lemma}/{tag}" for lemma, tag in pos_tag(caption))
    return f"{caption}#{tokens}#0.0#0.0"


def parse_caption_line(line: str) -> str:
    """The caption part of a HumanML3D text line (tolerates lines with only the caption)."""
    return line.split("#", 1)[0].strip()


def caption_key(content: str, style: str) -> str:
    """A stable key for grouping clips (used to stratify splits)."""
    return f"{content}|{style}"
