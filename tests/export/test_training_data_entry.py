"""The manifest's training_data from a dataset summary: a merged dataset's entry names every source's licence and
attribution (the CMU terms and HumanML3D's beside Bandai-Namco's), and a summary without a licence is refused."""
from __future__ import annotations

import json

import pytest

from t2m.export.kit.runs import training_data_entry


def test_a_merged_summary_names_every_sources_terms(tmp_path):
    summary = {"name": "a+b", "license": "CC BY-NC 4.0", "sources": [
        {"prefix": "bn-", "name": "bandai", "license": "CC BY-NC 4.0", "attribution": "Kobayashi et al."},
        {"prefix": "cmu-", "name": "cmu", "license": "CMU terms; sentences: HumanML3D, MIT",
         "attribution": "mocap.cs.cmu.edu"}]}
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    entry = training_data_entry(tmp_path / "summary.json")
    assert entry["license"] == "CC BY-NC 4.0"
    assert "bandai (CC BY-NC 4.0): Kobayashi et al." in entry["attribution"]
    assert "cmu (CMU terms; sentences: HumanML3D, MIT): mocap.cs.cmu.edu" in entry["attribution"]


def test_a_summary_without_a_licence_is_refused(tmp_path):
    (tmp_path / "summary.json").write_text(json.dumps({"name": "x"}))
    with pytest.raises(ValueError, match="field 'license' is missing"):
        training_data_entry(tmp_path / "summary.json")
