"""The one error type of the bundle contract."""
from __future__ import annotations

__all__ = ["BundleError"]


class BundleError(ValueError):
    """A bundle that does not satisfy the contract; the message names the bundle file or manifest field at fault."""
