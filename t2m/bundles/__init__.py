"""The bundles shipped inside the package (data only): `default/` is the model `t2m serve` uses when none is named;
every embedded bundle can be named by its folder name wherever a bundle directory is asked for (`--model masked`)."""
from __future__ import annotations

from pathlib import Path

__all__ = ["DEFAULT_BUNDLE", "EMBEDDED_BUNDLES", "resolve_bundle"]

_HERE = Path(__file__).resolve().parent
DEFAULT_BUNDLE = _HERE / "default"
EMBEDDED_BUNDLES: dict[str, Path] = {path.name: path for path in sorted(_HERE.iterdir())
                                     if (path / "manifest.json").is_file()}


def resolve_bundle(path: str | Path) -> Path:
    """A bundle directory as given, or, when no such directory exists, the embedded bundle of that name."""
    given = Path(path)
    if not given.exists() and str(path) in EMBEDDED_BUNDLES:
        return EMBEDDED_BUNDLES[str(path)]
    return given
