"""The bundles shipped inside the package (data only): `default/` is the model `t2m serve` uses when none is named."""
from __future__ import annotations

from pathlib import Path

__all__ = ["DEFAULT_BUNDLE"]

DEFAULT_BUNDLE = Path(__file__).resolve().parent / "default"
