"""Replace the files an embedded bundle shares with the default bundle (same name, same sha256 in both manifests:
the MiniLM text encoder, its tokenizer, the caption index) by relative links to the default's copy.

Why: the embedded bundles count against the project's ~100 MB budget, and three copies of the same 23 MB text
encoder would spend half of it. Each bundle keeps its own manifest and still verifies (the hashes are read through
the link); a wheel or `cp -L` materialises the links, so a copied bundle stays self-contained.
Usage: python scripts/share_bundle_files.py [t2m/bundles/masked ...]   (default: every embedded bundle)
"""
from __future__ import annotations

import json
import os
import sys
from pathlib import Path

from t2m.bundles import DEFAULT_BUNDLE, EMBEDDED_BUNDLES

MIN_BYTES = 64 * 1024  # small files (mean.npy, std.npy) stay plain copies: a link would save nothing worth its cost


def share_files(bundle: Path, reference: Path = DEFAULT_BUNDLE) -> list[str]:
    """Link every file of ``bundle`` whose manifest entry equals ``reference``'s; returns the linked names."""
    files = json.loads((bundle / "manifest.json").read_text())["files"]
    reference_files = json.loads((reference / "manifest.json").read_text())["files"]
    linked = []
    for name, entry in files.items():
        if reference_files.get(name) != entry or entry["bytes"] < MIN_BYTES or (bundle / name).is_symlink():
            continue
        target = os.path.relpath(reference / name, bundle)
        (bundle / name).unlink()
        (bundle / name).symlink_to(target)
        linked.append(name)
    return linked


def main(argv: list[str]) -> int:
    bundles = [Path(arg) for arg in argv] or [path for path in EMBEDDED_BUNDLES.values() if path != DEFAULT_BUNDLE]
    for bundle in bundles:
        print(f"{bundle}: linked {', '.join(share_files(bundle)) or 'nothing'}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
