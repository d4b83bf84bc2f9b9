"""The bundles shipped inside the package (data only): `default/` is the model `t2m serve` uses when none is named."""
from __future__ import annotations

from pathlib import Path

__all__ = ["DEFAULT_BUNDLE", "bundle_argument"]

DEFAULT_BUNDLE = Path(__file__).resolve().parent / "default"


def bundle_argument(path: Path) -> Path:
    """A bundle named on the command line: the word `default` is the embedded model (`t2m serve --model default
    --model models/momask`, `t2m bench --bundle default`), wherever the package is installed."""
    return DEFAULT_BUNDLE if str(path) == "default" else path
