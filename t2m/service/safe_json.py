"""Client input echoed in an error body, made encodable as UTF-8 JSON whatever the client sent.

A 422 echoes the offending input (pydantic's `input`, `loc` and `ctx`), and that input can be anything JSON or a
non-JSON body decodes to: lone UTF-16 surrogates ("\\ud800" is valid JSON but no UTF-8), raw bytes that are no UTF-8
(a text/plain or form body), NaN and Infinity (no JSON), structures nested deeper than the encoders recurse. Any of
them made the error handler itself fail, so the client got a 500 instead of the 4xx. `json_safe` turns an echo into
plain JSON values: bad characters and bytes as backslash escapes (the client sees what it sent), non-finite floats as
strings, nesting beyond `MAX_ECHO_DEPTH` as a placeholder, other objects through FastAPI's encoder.
"""
from __future__ import annotations

import math
from typing import Any

from fastapi.encoders import jsonable_encoder

__all__ = ["MAX_ECHO_DEPTH", "TOO_DEEP", "json_safe", "safe_text"]

MAX_ECHO_DEPTH = 32   # a request's own structure is 4 levels deep; deeper echoes only repeat the attacker's brackets
TOO_DEEP = "<nested too deep to echo>"


def safe_text(text: str) -> str:
    """`text` with every character UTF-8 cannot hold (lone surrogates) written as its backslash escape."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return text.encode("utf-8", "backslashreplace").decode("utf-8")
    return text


def json_safe(value: Any, depth: int = 0) -> Any:
    """`value` as JSON values that `json.dumps(..., allow_nan=False)` encodes and UTF-8 holds."""
    if value is None or isinstance(value, (bool, int)):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else str(value)
    if isinstance(value, str):
        return safe_text(value)
    if isinstance(value, (bytes, bytearray, memoryview)):
        return bytes(value).decode("utf-8", "backslashreplace")
    if depth >= MAX_ECHO_DEPTH:
        return TOO_DEEP
    if isinstance(value, dict):
        return {safe_text(str(key)): json_safe(item, depth + 1) for key, item in value.items()}
    if isinstance(value, (list, tuple, set, frozenset)):
        return [json_safe(item, depth + 1) for item in value]
    try:   # pydantic models, exceptions in `ctx`, enums, decimals, ...: FastAPI's encoder gives plain JSON values
        return json_safe(jsonable_encoder(value), depth + 1)
    except Exception:   # an object it cannot encode is still described
        return _describe(value)


def _describe(value: object) -> str:
    """The object's text, or its type's name when even str() fails."""
    try:
        return safe_text(str(value))
    except Exception:
        return f"<{type(value).__name__}>"
