"""Action-balanced sampling (t2m.model.data.balancing) and its use by the GPT's length-bucketed sampler."""
from __future__ import annotations

from collections import Counter

import numpy as np
import pytest
import torch

from t2m.model.data.balancing import OTHER, action_masses, balanced_weights, item_action
from t2m.model.data.datasets import LengthBucketSampler

IDS = ([f"dataset-2_walk_active_{i:03d}" for i in range(90)]
       + [f"dataset-1_walk-back_sad_{i:03d}" for i in range(9)]
       + ["dataset-1_kick_normal_001_p0"])


@pytest.mark.parametrize("item_id, action", [
    ("dataset-1_walk-back_happy_003", "walk-back"),
    ("Mdataset-2_wave-left-hand_elderly_017", "wave-right-hand"),    # a mirror waves the other hand
    ("Mdataset-1_walk-left_not-confident_002_p1", "walk-right"),
    ("dataset-1_kick_normal_001_p0", "kick"),
    ("012314", OTHER),
    ("synthetic_walk_3", OTHER),
    ("bn-dataset-1_walk-back_happy_003", "walk-back"),                # a merged dataset's source prefix
    ("Mbn-dataset-2_wave-left-hand_elderly_017", "wave-right-hand"),
    ("cmu-01_01_002510", OTHER),                                      # no label in the id, no sentences given
])
def test_item_action_reads_the_content_label(item_id, action):
    assert item_action(item_id) == action


def test_power_sets_each_actions_mass():
    natural = action_masses(IDS, balanced_weights(IDS, 1.0))
    assert natural == pytest.approx({"walk": 0.9, "walk-back": 0.09, "kick": 0.01})
    uniform = action_masses(IDS, balanced_weights(IDS, 0.0))
    assert uniform == pytest.approx({"walk": 1 / 3, "walk-back": 1 / 3, "kick": 1 / 3})
    half = action_masses(IDS, balanced_weights(IDS, 0.5))
    total = 90 ** 0.5 + 9 ** 0.5 + 1
    assert half == pytest.approx({"walk": 90 ** 0.5 / total, "walk-back": 3 / total, "kick": 1 / total})
    weights = balanced_weights(IDS, 0.3)
    assert weights.sum() == pytest.approx(1.0)
    assert len(set(weights[:90].round(12))) == 1     # items of one action share its mass equally


def test_bad_power_or_no_items_is_refused():
    with pytest.raises(ValueError, match="power"):
        balanced_weights(IDS, 1.5)
    with pytest.raises(ValueError, match="no items"):
        balanced_weights([], 0.5)


def test_weighted_bucket_sampler_draws_rare_items_by_their_weight():
    weights = balanced_weights(IDS, 0.0)
    counts = [5 + i % 40 for i in range(len(IDS))]
    sampler = LengthBucketSampler(counts, batch_size=10, weights=weights, generator=torch.Generator().manual_seed(0))
    drawn = Counter()
    for _ in range(60):
        batches = list(sampler)
        assert sum(len(b) for b in batches) == len(IDS)      # an epoch is still len(items) draws
        for batch in batches:
            drawn.update(item_action(IDS[i]) for i in batch)
    shares = {action: n / sum(drawn.values()) for action, n in drawn.items()}
    assert shares["kick"] == pytest.approx(1 / 3, abs=0.03)  # 1 item of 100, drawn a third of the time
    assert shares["walk"] == pytest.approx(1 / 3, abs=0.03)


def test_unweighted_bucket_sampler_still_visits_every_item_once():
    counts = np.arange(37) % 11 + 1
    batches = list(LengthBucketSampler(counts, batch_size=8, generator=torch.Generator().manual_seed(1)))
    assert sorted(i for batch in batches for i in batch) == list(range(37))
    with pytest.raises(ValueError, match="weights"):
        LengthBucketSampler(counts, batch_size=8, weights=[1.0, 2.0])


@pytest.mark.parametrize("sentences, action", [
    (["a person jumped forward three times"], "jump"),
    (["someone walks, then does a cartwheel"], "cartwheel"),         # the rarer action wins over the walk
    (["a person is performing a ballet dance"], "dance"),
    (["a person who is prone pushes himself up", "the man gets up from the floor"], "get-up"),
    (["person sprints forward three steps"], "run"),
    (["a man stands still"], OTHER),
    ([], OTHER),
])
def test_items_without_a_label_are_grouped_by_their_sentences(sentences, action):
    assert item_action("cmu-07_03_000100", sentences) == action
    assert item_action("Mcmu-07_03_000100", sentences) == action


def test_a_few_new_jumps_are_lifted_beside_many_walks():
    """Merged Bandai-Namco + CMU ids: the CMU jumps form their own action, so balancing lifts them; without
    their sentences they would sink into one OTHER group with every CMU clip."""
    ids = [f"bn-dataset-2_walk_active_{i:03d}" for i in range(300)] + [f"cmu-0{i}_01_000000" for i in range(4)] + \
        [f"cmu-1{i}_02_000000" for i in range(6)]
    sentences = {i: (["a person jumps up"] if i.startswith("cmu-0") else ["a person walks in a circle"]) for i in ids}
    masses = action_masses(ids, balanced_weights(ids, 0.3, sentences.__getitem__), sentences.__getitem__)
    assert set(masses) == {"walk", "jump"}
    assert masses["jump"] == pytest.approx(4 ** 0.3 / (4 ** 0.3 + 306 ** 0.3))
    assert set(action_masses(ids, balanced_weights(ids, 0.3))) == {"walk", OTHER}   # control: ids alone
