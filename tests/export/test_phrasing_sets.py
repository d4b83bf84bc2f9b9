"""The hand-written phrasing sets that calibrate the unknown-text warning (t2m index-captions --phrasings): each
sentence in one place only (known or unknown, calibration or held-out evaluation), none a probe's phrasing (the
probes measure the model; a sentence in both would let one tune the other), and the merged-data set's known
sentences a superset of the Bandai set's. The Bandai set predates the action probes, one of which later
took its "someone does a cartwheel"; it is checked against the kinematic probes only."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from t2m.export.writing.index_captions import DEFAULT_PHRASINGS
from t2m.model.evaluation.action_probes import ACTION_PROBES
from t2m.model.evaluation.probes import PROBES

FOLDER = DEFAULT_PHRASINGS.parent
SETS = sorted(FOLDER.glob("*.json"))
MERGED = FOLDER / "bandai_cmu_known_unknown.json"


def sentences(path: Path) -> dict[tuple[str, str], list[str]]:
    data = json.loads(path.read_text())
    return {(part, kind): data[part][kind] for part in ("calibration", "evaluation") for kind in ("known", "unknown")}


@pytest.mark.parametrize("path", SETS, ids=[path.name for path in SETS])
def test_every_sentence_stands_in_one_place_only_and_is_no_probe(path):
    groups = sentences(path)
    everything = [sentence for group in groups.values() for sentence in group]
    assert len(everything) == len(set(everything)), "a sentence stands in two places"
    assert all(len(group) >= 20 for group in groups.values())
    specs = PROBES if path == DEFAULT_PHRASINGS else (*PROBES, *ACTION_PROBES)
    probes = {phrasing for spec in specs for phrasing in (*spec.phrasings, *spec.reference_phrasings)}
    assert not probes & set(everything)


def test_the_merged_set_keeps_every_bandai_known_sentence_and_moves_the_cmu_actions_to_known():
    bandai, merged = sentences(DEFAULT_PHRASINGS), sentences(MERGED)
    for part in ("calibration", "evaluation"):
        assert set(bandai[part, "known"]) < set(merged[part, "known"])
        moved = set(bandai[part, "unknown"]) & set(merged[part, "known"])
        assert moved and all(any(word in sentence for word in ("jump", "hop", "cartwheel")) for sentence in moved)
        assert set(merged[part, "unknown"]) - set(bandai[part, "unknown"])   # new unknown actions were added
