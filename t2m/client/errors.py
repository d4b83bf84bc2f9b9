"""Exceptions of the SDK: one per way a request can fail, so callers can retry exactly what is retryable."""
from __future__ import annotations

from typing import Any

__all__ = ["AuthError", "OverloadedError", "ServerError", "T2MConnectionError", "T2MError", "ValidationError"]


class T2MError(Exception):
    """Any failure of a t2m request; `status_code` is None when no HTTP answer came back."""

    def __init__(self, message: str, status_code: int | None = None, detail: Any = None) -> None:
        super().__init__(message)
        self.status_code = status_code
        self.detail = detail


class ValidationError(T2MError, ValueError):
    """422: the request broke a rule; `fields` are the dotted names of the offending fields (e.g. segments.0.text)."""

    def __init__(self, message: str, fields: list[str], errors: list[dict[str, Any]], status_code: int = 422) -> None:
        super().__init__(message, status_code, errors)
        self.fields = fields
        self.errors = errors


class AuthError(T2MError):
    """401/403: the server needs an API key (T2MClient(api_key=...)) or refused the one given."""


class OverloadedError(T2MError):
    """429: too many requests are waiting; try again after `retry_after` seconds."""

    def __init__(self, message: str, retry_after: float | None, status_code: int = 429, detail: Any = None) -> None:
        super().__init__(message, status_code, detail)
        self.retry_after = retry_after


class ServerError(T2MError):
    """5xx: the server failed (500), is loading (503, see retry_after) or timed out (504)."""

    def __init__(self, message: str, status_code: int, detail: Any = None, retry_after: float | None = None) -> None:
        super().__init__(message, status_code, detail)
        self.retry_after = retry_after


class T2MConnectionError(T2MError):
    """No answer: the server is unreachable or the connection failed."""
