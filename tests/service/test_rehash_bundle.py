"""scripts/rehash_bundle.py: a hand-edited model card breaks a bundle's verification until it is re-hashed, and
re-hashing touches nothing but the changed file's entry."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from scripts.rehash_bundle import main, rehash

REPO = Path(__file__).resolve().parents[2]


def test_an_edited_card_verifies_again_after_rehash(random_bundle, tmp_path):
    from t2m.bundle import BundleError
    from t2m.export.writing.verify import verify_bundle

    bundle = tmp_path / "bundle"
    shutil.copytree(random_bundle, bundle)
    before = json.loads((bundle / "manifest.json").read_text())
    (bundle / "MODEL_CARD.md").write_text((bundle / "MODEL_CARD.md").read_text() + "\nA corrected sentence.\n")
    with pytest.raises(BundleError, match=r"MODEL_CARD\.md"):
        verify_bundle(bundle)
    assert rehash(bundle) == ["MODEL_CARD.md"]
    after = verify_bundle(bundle)
    assert {k: v for k, v in after.items() if k != "files"} == {k: v for k, v in before.items() if k != "files"}
    assert {k: v for k, v in after["files"].items() if k != "MODEL_CARD.md"} == {
        k: v for k, v in before["files"].items() if k != "MODEL_CARD.md"}
    assert rehash(bundle) == []                       # nothing changed since


def test_a_directory_that_is_no_bundle_is_refused_in_one_line(tmp_path, capsys):
    assert main([str(tmp_path)]) == 2
    assert capsys.readouterr().err.strip() == f"{tmp_path}: no manifest.json (not a bundle directory)"
    assert main([]) == 2
