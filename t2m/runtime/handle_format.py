"""What both handle formats share (service/handles.py's `t2m1.` codes, service/recipes.py's `t2m2.` recipes): the
error naming the part of a handle that is wrong, the checksum's size, the string's unpacking and the checks of a
number read from a handle."""
from __future__ import annotations

import base64
import binascii
import math
from typing import Any

from t2m.runtime.limits import MAX_GUIDANCE, MAX_HANDLE_CHARS, MAX_SEED
from t2m.runtime.types import ModelLimits

__all__ = [
    "CHECKSUM_BYTES",
    "HANDLE_PREFIX",
    "MAX_HANDLE_CHARS",
    "HandleError",
    "checked_number",
    "model_seed_guidance",
    "no_constant",
    "unpack_handle",
]

HANDLE_PREFIX = "t2m1."
CHECKSUM_BYTES = 16


class HandleError(ValueError):
    """A handle that cannot be used with this model; `part` names what is wrong ("handle.segments.1.codes")."""

    def __init__(self, part: str, message: str) -> None:
        super().__init__(f"{part}: {message}")
        self.part = part


def unpack_handle(handle: str, prefix: str = HANDLE_PREFIX, max_chars: int = MAX_HANDLE_CHARS) -> tuple[bytes, bytes]:
    """(checksum, compressed body) of a handle string of the format `prefix` names."""
    if not isinstance(handle, str) or not handle.startswith(prefix):
        raise HandleError("handle", f"not a t2m handle of this model (it starts with {prefix!r}, the format "
                                    "version)")
    if len(handle) > max_chars:
        raise HandleError("handle", f"{len(handle)} characters, more than {max_chars}")
    text = handle[len(prefix):]
    try:
        packed = base64.b64decode(text + "=" * (-len(text) % 4), altchars=b"-_", validate=True)
    except (binascii.Error, ValueError):
        raise HandleError("handle", "not base64url") from None
    if len(packed) <= CHECKSUM_BYTES:
        raise HandleError("handle", "truncated")
    return packed[:CHECKSUM_BYTES], packed[CHECKSUM_BYTES:]


def no_constant(name: str) -> None:
    raise ValueError(f"{name} is not a number")


def checked_number(meta: dict[str, Any], key: str, low: float, high: float, *, integer: bool = False,
            low_open: bool = False) -> Any:
    value = meta[key]
    kinds = (int,) if integer else (int, float)
    if isinstance(value, bool) or not isinstance(value, kinds) or not math.isfinite(value) or not (
            (low < value) if low_open else (low <= value)) or value > high:
        kind = "an integer" if integer else "a number"
        raise HandleError(f"handle.{key}", f"must be {kind} in {'(' if low_open else '['}{low:g}, {high:g}], got "
                                           f"{value!r}")
    return value


def model_seed_guidance(meta: dict[str, Any], limits: ModelLimits) -> tuple[int, float]:
    """(seed, guidance) of a handle's description made by the model of `limits` (its name and version), checked."""
    if meta["model"] != limits.name or meta["version"] != limits.version:
        raise HandleError("handle.model", f"made by model {meta['model']!r} version {meta['version']!r}, not by "
                                          f"{limits.name!r} version {limits.version!r}: a handle is edited by the "
                                          "model that made it")
    seed = checked_number(meta, "seed", 0, MAX_SEED, integer=True)
    return seed, float(checked_number(meta, "guidance", 0.0, MAX_GUIDANCE))
