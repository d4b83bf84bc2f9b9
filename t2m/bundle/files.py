"""Bundle files: the manifest's `files` table (sha256 + size per file) and its check against the disk."""
from __future__ import annotations

import hashlib
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from t2m.bundle.errors import BundleError
from t2m.bundle.manifest import MANIFEST_NAME

__all__ = ["check_files", "files_table", "sha256_of"]


def sha256_of(path: Path, chunk: int = 1 << 20) -> str:
    """Hex sha256 of a file, read in chunks (the T2M-GPT import's graphs are about 1 GB)."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(chunk), b""):
            digest.update(block)
    return digest.hexdigest()


def files_table(bundle_dir: Path, names: Iterable[str]) -> dict[str, dict[str, Any]]:
    """{name: {sha256, bytes}} of the named files, sorted by name: what manifest.json's `files` holds."""
    return {name: {"sha256": sha256_of(bundle_dir / name), "bytes": (bundle_dir / name).stat().st_size}
            for name in sorted(names)}


def check_files(bundle_dir: Path, files: Mapping[str, Any], *, check_hashes: bool = True,
                required: Iterable[str] = ()) -> None:
    """Every required file present and listed (`required`: the manifest's family's
    `required_files(manifest)`); every listed file inside the bundle with its size (and sha256)."""
    for name in required:
        if not (bundle_dir / name).is_file():
            raise BundleError(f"{bundle_dir / name}: missing file")
        if name not in files:
            raise BundleError(f"{MANIFEST_NAME}: field 'files' does not list {name!r}")
    for name, entry in files.items():
        if Path(name).is_absolute() or ".." in Path(name).parts:
            raise BundleError(f"{MANIFEST_NAME}: field 'files.{name}' must be a path inside the bundle")
        if (not isinstance(entry, Mapping) or not isinstance(entry.get("sha256"), str)
                or not isinstance(entry.get("bytes"), int) or isinstance(entry.get("bytes"), bool)):
            raise BundleError(f"{MANIFEST_NAME}: field 'files.{name}' must be {{sha256: str, bytes: int}}")
        path = bundle_dir / name
        if not path.is_file():
            raise BundleError(f"{path}: missing file (listed in {MANIFEST_NAME} 'files')")
        size = path.stat().st_size
        if size != entry["bytes"]:
            raise BundleError(f"{path}: size mismatch, {size} bytes on disk, {MANIFEST_NAME} says {entry['bytes']}")
        if check_hashes:
            digest = sha256_of(path)
            if digest != entry["sha256"].lower():
                raise BundleError(f"{path}: sha256 mismatch, {digest} on disk, {MANIFEST_NAME} says "
                                  f"{entry['sha256']}")
