"""Rewrite a bundle's manifest `files` table after a hand edit of one of its files (usually MODEL_CARD.md).

Why: every file of a bundle is pinned by sha256 in manifest.json, so a corrected model card must be re-hashed or the
bundle no longer verifies. Nothing else in the manifest changes; the bundle is verified after the rewrite.
Usage: python scripts/rehash_bundle.py t2m/bundles/gpt [more bundles]
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

from t2m.export.writing.bundle import write_bundle


def rehash(bundle: Path) -> list[str]:
    """Re-hash every file the manifest lists; returns the names whose entry changed."""
    manifest = json.loads((bundle / "manifest.json").read_text(encoding="utf-8"))
    before = manifest["files"]
    after = write_bundle(bundle, {name: bundle / name for name in before}, manifest)["files"]
    return [name for name in after if after[name] != before.get(name)]


def main(argv: list[str]) -> int:
    if not argv:
        print("usage: python scripts/rehash_bundle.py BUNDLE_DIR [...]", file=sys.stderr)
        return 2
    for arg in argv:
        bundle = Path(arg)
        if not (bundle / "manifest.json").is_file():
            print(f"{bundle}: no manifest.json (not a bundle directory)", file=sys.stderr)
            return 2
        print(f"{bundle}: re-hashed {', '.join(rehash(bundle)) or 'nothing (no file changed)'}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
