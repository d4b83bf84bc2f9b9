"""Request building and response interpretation shared by the sync and async clients (no I/O here)."""
from __future__ import annotations

import contextlib
import json
from collections.abc import Iterator, Sequence
from typing import Any

import httpx
import numpy as np

from t2m.client.errors import AuthError, OverloadedError, ServerError, T2MConnectionError, T2MError, ValidationError
from t2m.client.models import (
    EditLike,
    FrameChunk,
    Motion,
    RawResult,
    SegmentsLike,
    Upload,
    edits_json,
    to_segments,
    warnings_of,
)

__all__ = ["DEFAULT_TIMEOUT_S", "DEFAULT_URL", "StreamReader", "auth_headers", "connection_errors", "edit_body",
           "raise_for_answer", "raw_result", "request_body", "stream_body"]

DEFAULT_URL = "http://127.0.0.1:8000"
DEFAULT_TIMEOUT_S = 120.0


def request_body(segments: SegmentsLike, fmt: str, seed: int | None, guidance: float | None,
                 temperature: float, top_k: int | None, model: str | None = None,
                 stream: bool = False) -> dict[str, Any]:
    """The POST /generate body; `model` and `stream` only when used, so servers from before them still accept it."""
    body: dict[str, Any] = {"segments": [s.to_json() for s in to_segments(segments)], "format": fmt, "seed": seed,
                            "guidance": guidance, "temperature": temperature, "top_k": top_k}
    if model is not None:
        body["model"] = model
    if stream:
        body["stream"] = True
    return body


def edit_body(motion: Motion | str | Upload, edits: Sequence[EditLike], fmt: str,
              model: str | None) -> dict[str, Any]:
    """The POST /edit body for a Motion (its handle), a handle string or an Upload (a motion to encode)."""
    if isinstance(motion, Upload):
        body: dict[str, Any] = {"motion": motion.to_json(), "edits": edits_json(edits), "format": fmt}
        if model is not None:
            body["model"] = model
        return body
    handle = motion if isinstance(motion, str) else motion.handle
    if not handle:
        raise T2MError("this motion has no handle to edit (a json answer of a server with POST /edit carries one; "
                       "send Upload.of_motion(motion) to have the model encode its frames)")
    body = {"handle": handle, "edits": edits_json(edits), "format": fmt}
    if model is not None:
        body["model"] = model
    return body


def stream_body(segments: SegmentsLike, seed: int | None, guidance: float | None, temperature: float,
                top_k: int | None, model: str | None) -> dict[str, Any]:
    """The body of a streamed json request."""
    return request_body(segments, "json", seed, guidance, temperature, top_k, model, stream=True)


@contextlib.contextmanager
def connection_errors(http: httpx.Client | httpx.AsyncClient) -> Iterator[None]:
    """httpx's transport failures (refused, reset, timed out) as T2MConnectionError naming the server."""
    try:
        yield
    except httpx.TransportError as error:
        raise T2MConnectionError(f"cannot reach {http.base_url}: {error}") from error


def auth_headers(api_key: str | None) -> dict[str, str]:
    return {"Authorization": f"Bearer {api_key}"} if api_key else {}


def _retry_after(response: httpx.Response) -> float | None:
    try:
        return float(response.headers["Retry-After"])
    except (KeyError, ValueError):
        return None


def _detail(response: httpx.Response) -> Any:
    try:
        return response.json().get("detail")
    except (ValueError, AttributeError):
        return response.text[:500]


def _field(loc: list[Any]) -> str:
    parts = [str(part) for part in loc]
    return ".".join(parts[1:] if parts and parts[0] == "body" else parts) or "body"


def raise_for_answer(response: httpx.Response) -> None:
    """Turn an error answer into the matching T2MError subclass; success passes."""
    code = response.status_code
    if code < 400:
        return
    detail = _detail(response)
    if code == 422 and isinstance(detail, list):
        fields = [_field(e.get("loc", [])) for e in detail if isinstance(e, dict)]
        message = "; ".join(f"{_field(e.get('loc', []))}: {e.get('msg', '')}" for e in detail if isinstance(e, dict))
        raise ValidationError(f"invalid request: {message}", fields=fields, errors=detail)
    text = detail if isinstance(detail, str) else str(detail)
    if code in (401, 403):
        raise AuthError(f"HTTP {code}: {text}", code, detail)
    if code == 429:
        raise OverloadedError(f"HTTP 429: {text}", _retry_after(response), code, detail)
    if code >= 500:
        raise ServerError(f"HTTP {code}: {text}", code, detail, _retry_after(response))
    if code in (400, 413, 422):
        raise ValidationError(f"HTTP {code}: {text}", fields=[], errors=[{"msg": text}], status_code=code)
    raise T2MError(f"HTTP {code}: {text}", code, detail)


def raw_result(response: httpx.Response) -> RawResult:
    seed = response.headers.get("X-Seed")
    return RawResult(content=response.content, media_type=response.headers.get("content-type", ""),
                     seed=int(seed) if seed is not None else None,
                     warnings=warnings_of(response.headers.get("X-T2M-Warnings")))


class StreamReader:
    """The lines of a streamed answer ("stream": true) in order: FrameChunks as they come, then the whole Motion (its
    frames put together from the chunks); an error message raises as the same answer without a stream would."""

    def __init__(self) -> None:
        self.fps: int | None = None
        self.chunks: list[np.ndarray] = []
        self.received = 0
        self.motion: Motion | None = None

    def feed(self, line: str) -> FrameChunk | Motion | None:
        """One line -> a FrameChunk, the Motion (after the end message) or None (the start message, a blank line)."""
        if not line.strip():
            return None
        message = json.loads(line)
        kind = message.get("type")
        if kind == "start":
            self.fps = int(message["fps"])
            return None
        if kind == "frames":
            if self.fps is None or message["start_frame"] != self.received:
                raise T2MError(f"the stream is out of order: frames from {message['start_frame']} after "
                               f"{self.received} frames")
            frames = np.asarray(message["frames"], dtype=np.float32)
            self.chunks.append(frames)
            self.received += len(frames)
            return FrameChunk(start_frame=message["start_frame"], frames=frames, fps=self.fps)
        if kind == "end":
            if message.get("frame_count") != self.received:
                raise T2MError(f"the stream carried {self.received} frames, its end message says "
                               f"{message.get('frame_count')}")
            whole = np.concatenate(self.chunks) if self.chunks else np.zeros((0, len(message["joints"]), 3), np.float32)
            self.motion = Motion.from_json({**message, "frames": whole})
            return self.motion
        if kind == "error":
            status, detail = int(message.get("status", 500)), message.get("detail", "")
            raise ServerError(f"HTTP {status} during the stream: {detail}", status, detail)
        raise T2MError(f"unknown stream message type {kind!r}")

    def finish(self) -> None:
        """After the last line: a stream cut short (no end message) is a connection failure."""
        if self.motion is None:
            raise T2MConnectionError(f"the stream ended after {self.received} frames without its end message")
