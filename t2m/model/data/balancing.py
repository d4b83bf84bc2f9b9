"""Action-balanced sampling weights, so that rare actions are seen often enough to be learned.

The Bandai-Namco data is very uneven: ~600 items each of the dataset-2 gestures and turns, 30 of walk-back or bow,
2 of kick. Sampled uniformly, a rare action is ~0.5% of the batches and the first model learned to ignore it (walked
forward when asked to walk backwards). With ``power`` p, the items of an action with n items get a total sampling
mass proportional to n**p: p = 1 is the natural distribution, p = 0 gives every action the same mass, and values in
between (the default model uses 0.3) lift the rare actions without letting two kick items fill a tenth of every batch.

The action is the content label in the item id (``dataset-1_walk-back_happy_003``, mirrored ``M...`` with left/right
swapped, pieces ``..._p1``; a merged dataset's source prefix, ``bn-`` / ``Mbn-``, is skipped). An item without one
(the captioned CMU trials, HumanML3D) takes the first action its sentences name (`SENTENCE_ACTIONS`: jump, cartwheel,
dance, kick, get-up, run, walk, ...), so that a few minutes of jumps are one group beside Bandai-Namco's hours of
walks instead of vanishing into one "other" group with every CMU clip; sentences naming none of them, or
no sentences, leave it in OTHER.
"""
from __future__ import annotations

import json
import re
from collections import Counter
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from t2m.model.data.captions import mirror_label

__all__ = ["BALANCE_POWER_HELP", "SENTENCE_ACTIONS", "Captions", "action_masses", "balanced_weights", "item_action",
           "run_sampling_weights"]

_BANDAI_ID = re.compile(r"^(M?)(?:[a-z0-9]+[-_](?=dataset-))?dataset-\d+_([a-z-]+)_[a-z-]+_\d+(?:_p\d+)?$")
# (action, pattern) in order of precedence: a cartwheel clip that also walks is a cartwheel
SENTENCE_ACTIONS: tuple[tuple[str, re.Pattern[str]], ...] = tuple((action, re.compile(pattern)) for action, pattern in (
    ("cartwheel", r"cartwheel|handstand|hand ?spring|\bflip|somersault|\broll"),
    ("jump", r"\bjump|\bhop|\bleap|\bskip"),
    ("dance", r"\bdanc|ballet|waltz|salsa"),
    ("get-up", r"gets? up|stands? up|rises? from|lies? down|lying|crawl"),
    ("kick", r"\bkick"),
    ("throw", r"\bthrow|\bcatch|\bpitch|\bdribbl|\bbasketball|\bball\b"),
    ("sword", r"\bsword|\bfenc|\bswing|\bstab|\bslash"),
    ("run", r"\brun|\bjog|\bsprint|\bran\b"),
    ("walk", r"\bwalk|\bstep|\bstroll|\bmarch"),
))
OTHER = "other"
MASSES_FILE = "action_masses.json"
BALANCE_POWER_HELP = ("draw training items so each action's mass ~ (its item count)**p: 1 natural, 0 uniform over "
                      "actions (t2m.model.data.balancing)")


def item_action(item_id: str, captions: Sequence[str] = ()) -> str:
    """The action of a dataset item: its id's content label (as the mirrored motion does it), else the first of
    SENTENCE_ACTIONS its `captions` name, else OTHER."""
    match = _BANDAI_ID.match(item_id)
    if match is not None:
        mirrored, content = match.groups()
        return mirror_label(content) if mirrored else content
    text = " ".join(captions).lower()
    return next((action for action, pattern in SENTENCE_ACTIONS if pattern.search(text)), OTHER)


Captions = Callable[[str], Sequence[str]]
"""item id -> its sentences (a dataset reader's `captions`)."""


def _actions(item_ids: Sequence[str], captions: Captions | None) -> list[str]:
    return [item_action(i, captions(i) if captions is not None else ()) for i in item_ids]


def balanced_weights(item_ids: Sequence[str], power: float, captions: Captions | None = None) -> np.ndarray:
    """Per-item sampling probabilities (sum 1) giving each action a mass proportional to (its item count)**power;
    `captions` lets items without a labelled id be grouped by their sentences."""
    if not item_ids:
        raise ValueError("balanced_weights: no items")
    if not 0.0 <= power <= 1.0:
        raise ValueError(f"balance power must be in [0, 1], got {power}")
    actions = _actions(item_ids, captions)
    counts = Counter(actions)
    weights = np.array([counts[a] ** (power - 1.0) for a in actions], dtype=np.float64)
    return weights / weights.sum()


def action_masses(item_ids: Sequence[str], weights: np.ndarray, captions: Captions | None = None) -> dict[str, float]:
    """action -> its share of the samples under ``weights`` (for the training log)."""
    masses: dict[str, float] = {}
    for action, weight in zip(_actions(item_ids, captions), weights):
        masses[action] = masses.get(action, 0.0) + float(weight)
    return dict(sorted(masses.items(), key=lambda kv: -kv[1]))


def run_sampling_weights(item_ids: Sequence[str], power: float, run_dir: str | Path,
                         captions: Captions | None = None) -> np.ndarray | None:
    """A training run's item weights: None for the natural distribution (power >= 1), else the balanced weights,
    with each action's mass written to <run_dir>/action_masses.json so the run records how often it saw each."""
    if power >= 1.0:
        return None
    weights = balanced_weights(item_ids, power, captions)
    (Path(run_dir) / MASSES_FILE).write_text(json.dumps(action_masses(item_ids, weights, captions), indent=1))
    return weights
