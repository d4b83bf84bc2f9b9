"""Action-balanced sampling weights, so that rare actions are seen often enough to be learned.

The Bandai-Namco data is very uneven: ~600 items each of the dataset-2 gestures and turns, 30 of walk-back or bow,
2 of kick. Sampled uniformly, a rare action is ~0.5% of the batches and the first model learned to ignore it (walked
forward when asked to walk backwards). With ``power`` p, the items of an action with n items get a total sampling
mass proportional to n**p: p = 1 is the natural distribution, p = 0 gives every action the same mass, and values in
between (the default model uses 0.3) lift the rare actions without letting two kick items fill a tenth of every batch.

The action is the content label in the item id (``dataset-1_walk-back_happy_003``, mirrored ``M...`` with left/right
swapped, pieces ``..._p1``); ids of another form (HumanML3D's numbers, synthetic test data) form one group.
"""
from __future__ import annotations

import json
import re
from collections import Counter
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from t2m.model.data.captions import mirror_label

__all__ = ["BALANCE_POWER_HELP", "action_masses", "balanced_weights", "item_action", "run_sampling_weights"]

_BANDAI_ID = re.compile(r"^(M?)dataset-\d+_([a-z-]+)_[a-z-]+_\d+(?:_p\d+)?$")
OTHER = "other"
MASSES_FILE = "action_masses.json"
BALANCE_POWER_HELP = ("draw training items so each action's mass ~ (its item count)**p: 1 natural, 0 uniform over "
                      "actions (t2m.model.data.balancing)")


def item_action(item_id: str) -> str:
    """The action (content label, as the mirrored motion does it) of a dataset item id; OTHER if it has none."""
    match = _BANDAI_ID.match(item_id)
    if match is None:
        return OTHER
    mirrored, content = match.groups()
    return mirror_label(content) if mirrored else content


def balanced_weights(item_ids: Sequence[str], power: float) -> np.ndarray:
    """Per-item sampling probabilities (sum 1) giving each action a mass proportional to (its item count)**power."""
    if not item_ids:
        raise ValueError("balanced_weights: no items")
    if not 0.0 <= power <= 1.0:
        raise ValueError(f"balance power must be in [0, 1], got {power}")
    actions = [item_action(i) for i in item_ids]
    counts = Counter(actions)
    weights = np.array([counts[a] ** (power - 1.0) for a in actions], dtype=np.float64)
    return weights / weights.sum()


def action_masses(item_ids: Sequence[str], weights: np.ndarray) -> dict[str, float]:
    """action -> its share of the samples under ``weights`` (for the training log)."""
    masses: dict[str, float] = {}
    for item_id, weight in zip(item_ids, weights):
        action = item_action(item_id)
        masses[action] = masses.get(action, 0.0) + float(weight)
    return dict(sorted(masses.items(), key=lambda kv: -kv[1]))


def run_sampling_weights(item_ids: Sequence[str], power: float, run_dir: str | Path) -> np.ndarray | None:
    """A training run's item weights: None for the natural distribution (power >= 1), else the balanced weights,
    with each action's mass written to <run_dir>/action_masses.json so the run records how often it saw each."""
    if power >= 1.0:
        return None
    weights = balanced_weights(item_ids, power)
    (Path(run_dir) / MASSES_FILE).write_text(json.dumps(action_masses(item_ids, weights), indent=1))
    return weights
