"""An answer's handle: its motion's codes and everything needed to decode them again or to edit them (POST /edit),
in one compact string, so that the service keeps no state and any replica serves an edit.

Format (version 1): `t2m1.` + base64url without padding of `checksum || zlib(body)`:

- body = u32 little-endian length of `meta` || meta (compact JSON, UTF-8) || codes;
- meta = {"model", "version" (the manifest's), "seed", "guidance", "temperature", "top_k" (the request's options,
  resolved), "shape" (one code step: [] one code, [R] a residual row, [C, R] a joint-token row), "width" (bytes per
  code: 2 = uint16, 4 = uint32 when a codebook has more than 65536 codes), "segments": [{"text", "duration" (seconds
  or null: the model ended it), "steps"}]};
- codes = every segment's codes, in segment order, steps x shape values each, each less the layout's lowest code
  (0, or -1 where -1 marks an unused residual layer), little-endian unsigned of `width`;
- checksum = the first 16 bytes of SHA-256(body): corruption (a flipped byte, a truncated copy) is detected. It is
  not a signature: a client can make a handle of any codes, so everything in it is checked like any request field.

Decoding (`read_handle`) treats the string as untrusted input: its length, the decompressed size (bounded before
decompressing: no zip bomb), the checksum, the JSON's keys and types, the model's name and version, the segment count,
texts and durations (the API's limits), each segment's steps (1..max_tokens; a duration's steps are
round(duration * fps / frames_per_token)) and every code against the model's codebook(s) (types.CodeLayout). Every
failure is a HandleError naming the part of the handle that is wrong (a 422 over HTTP).
"""
from __future__ import annotations

import base64
import hashlib
import json
import struct
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from t2m.runtime.handle_format import (
    CHECKSUM_BYTES,
    HANDLE_PREFIX,
    MAX_HANDLE_CHARS,
    HandleError,
    checked_number,
    model_seed_guidance,
    no_constant,
    unpack_handle,
)
from t2m.runtime.limits import (
    MAX_DURATION_S,
    MAX_SEGMENTS,
    MAX_TEMPERATURE,
    MAX_TEXT_CHARS,
    MAX_TOTAL_S,
    MIN_DURATION_S,
)
from t2m.runtime.recipes import RECIPE_PREFIX, make_recipe, recipe_model
from t2m.runtime.types import GenerationRequest, ModelLimits, Motion, SegmentRequest, tokens_for_duration

__all__ = [
    "HANDLE_PREFIX",
    "MAX_HANDLE_CHARS",
    "HandleError",
    "HandleSegment",
    "MotionHandle",
    "answer_handle",
    "handle_model",
    "make_handle",
    "read_handle",
    "segment_seed",
]

MAX_META_BYTES = 64 * 1024        # 32 segments of 300 characters, escaped, and the rest
META_KEYS = ("model", "version", "seed", "guidance", "temperature", "top_k", "shape", "width", "segments")
SEGMENT_KEYS = ("text", "duration", "steps")
SEED_BITS = 31


@dataclass(frozen=True)
class HandleSegment:
    text: str
    duration: float | None
    codes: np.ndarray            # int64 [steps, *shape]


@dataclass(frozen=True)
class MotionHandle:
    """A decoded handle: the model it came from, the request's options and each segment's text, duration, codes."""

    model: str
    version: str
    seed: int
    guidance: float
    temperature: float
    top_k: int | None
    segments: list[HandleSegment]

    def request(self, segments: Sequence[SegmentRequest] | None = None, seed: int | None = None) -> GenerationRequest:
        """A request with the handle's options (and its own segments unless others are given)."""
        chosen = [SegmentRequest(s.text, s.duration) for s in self.segments] if segments is None else list(segments)
        return GenerationRequest(segments=chosen, seed=self.seed if seed is None else seed, guidance=self.guidance,
                                 temperature=self.temperature, top_k=self.top_k)


def segment_seed(seed: int, where: int | str) -> int:
    """The seed of an edit given none: from the handle's seed and where the edit is (a segment's index, or
    "append" / "prepend"), the same on every replica (SHA-256, 31 bits like the seeds the service picks)."""
    digest = hashlib.sha256(f"t2m-edit:{seed}:{where}".encode()).digest()
    return int.from_bytes(digest[:8], "little") >> (64 - SEED_BITS)


def _width(limits: ModelLimits) -> int:
    assert limits.codes is not None
    return 2 if max(limits.codes.bounds) - limits.codes.low <= 1 << 16 else 4


def answer_handle(limits: ModelLimits, request: GenerationRequest, motion: Motion) -> str | None:
    """The handle an answer of `motion` to `request` carries (the one place an answer's handle is made: POST
    /generate whole or streamed, POST /edit, `t2m generate`, `t2m edit`): the one its maker already set (an edit's
    recipe), else the handle of its codes."""
    return motion.handle if motion.handle is not None else make_handle(limits, request, motion.codes)


def make_handle(limits: ModelLimits, request: GenerationRequest, codes: Sequence[np.ndarray] | None) -> str | None:
    """The handle of an answer of the model of `limits` to `request` with these segment codes; None when the model's
    codes are not tokens (no `limits.codes`) or the motion carries none. A model whose answers are made again from
    their request (`limits.recipe`: the diffusion family) gets the recipe of `request` (service/recipes.py)."""
    if limits.recipe:
        return make_recipe(limits, request)
    layout = limits.codes
    if layout is None or codes is None or len(codes) != len(request.segments):
        return None
    width = _width(limits)
    arrays = [np.asarray(c).reshape(len(c), *layout.shape) for c in codes]
    meta = {"model": limits.name, "version": limits.version, "seed": int(request.seed),
            "guidance": float(request.guidance), "temperature": float(request.temperature),
            "top_k": None if request.top_k is None else int(request.top_k), "shape": list(layout.shape),
            "width": width,
            "segments": [{"text": s.text, "duration": s.duration, "steps": len(c)}
                         for s, c in zip(request.segments, arrays)]}
    meta_bytes = json.dumps(meta, separators=(",", ":"), ensure_ascii=False).encode()
    dtype = "<u2" if width == 2 else "<u4"
    codes_bytes = b"".join((a - layout.low).astype(dtype).tobytes() for a in arrays)
    body = struct.pack("<I", len(meta_bytes)) + meta_bytes + codes_bytes
    packed = hashlib.sha256(body).digest()[:CHECKSUM_BYTES] + zlib.compress(body, 9)
    return HANDLE_PREFIX + base64.urlsafe_b64encode(packed).rstrip(b"=").decode("ascii")


def _max_body(limits: ModelLimits) -> int:
    """The largest body a handle of this model can have: the meta and the codes of MAX_SEGMENTS longest segments."""
    assert limits.codes is not None
    return 4 + MAX_META_BYTES + MAX_SEGMENTS * limits.max_tokens * limits.codes.values * _width(limits)


def _unpack(handle: str, limits: ModelLimits) -> bytes:
    """The checked body of a handle string."""
    checksum, compressed = unpack_handle(handle)
    inflater = zlib.decompressobj()
    limit = _max_body(limits)
    try:
        body = inflater.decompress(compressed, limit + 1)
    except zlib.error:
        raise HandleError("handle", "corrupt (its compressed data does not decompress)") from None
    if len(body) > limit or inflater.unconsumed_tail:
        raise HandleError("handle", f"decompresses to more than {limit} bytes, the most a handle of model "
                                    f"{limits.name!r} holds")
    if not inflater.eof or inflater.unused_data:
        raise HandleError("handle", "corrupt (truncated, or data after its end)")
    if hashlib.sha256(body).digest()[:CHECKSUM_BYTES] != checksum:
        raise HandleError("handle.checksum", "does not match the handle's content (corrupted or altered)")
    return body


def handle_model(handle: str) -> tuple[str, str]:
    """The (name, version) of the model a handle names, read from its description alone (nothing else checked
    yet: `read_handle` does that with the model's limits). A diffusion model's recipe (service/recipes.py) too."""
    if isinstance(handle, str) and handle.startswith(RECIPE_PREFIX):
        return recipe_model(handle)
    _, compressed = unpack_handle(handle)
    try:
        start = zlib.decompressobj().decompress(compressed, 4 + MAX_META_BYTES)
    except zlib.error:
        raise HandleError("handle", "corrupt (its compressed data does not decompress)") from None
    meta, _ = _meta(start)
    name, version = meta["model"], meta["version"]
    if not isinstance(name, str) or not isinstance(version, str):
        raise HandleError("handle.model", "must name a model and its version")
    return name, version


def _meta(body: bytes) -> tuple[dict[str, Any], bytes]:
    """The description and the code bytes after it (all of them only in a whole body)."""
    if len(body) < 4:
        raise HandleError("handle", "truncated")
    (size,) = struct.unpack_from("<I", body)
    if size > min(MAX_META_BYTES, len(body) - 4):
        raise HandleError("handle", "its description is longer than the handle")
    try:
        meta = json.loads(body[4:4 + size].decode("utf-8"), parse_constant=no_constant)
    except (UnicodeDecodeError, ValueError):
        raise HandleError("handle", "its description is not JSON") from None
    if not isinstance(meta, dict) or sorted(meta) != sorted(META_KEYS):
        raise HandleError("handle", f"its description must have exactly the keys {', '.join(META_KEYS)}")
    return meta, body[4 + size:]


def read_handle(handle: str, limits: ModelLimits) -> MotionHandle:
    """The handle checked against the model of `limits` (see the module's docstring), or a HandleError."""
    layout = limits.codes
    if layout is None:
        raise HandleError("handle", f"model {limits.name!r} makes no token codes: its handles are recipes ('t2m2.')")
    meta, code_bytes = _meta(_unpack(handle, limits))
    seed, guidance = model_seed_guidance(meta, limits)
    temperature = float(checked_number(meta, "temperature", 0.0, MAX_TEMPERATURE, low_open=True))
    top_k = meta["top_k"]
    if top_k is not None:
        top_k = checked_number(meta, "top_k", 1, limits.codebook_size, integer=True)
    if meta["shape"] != list(layout.shape) or meta["width"] != _width(limits):
        raise HandleError("handle.shape", f"code steps of shape {meta['shape']!r} x {meta['width']!r} bytes; model "
                                          f"{limits.name!r} has {list(layout.shape)} x {_width(limits)}")
    rows = meta["segments"]
    if not isinstance(rows, list) or not 1 <= len(rows) <= MAX_SEGMENTS:
        raise HandleError("handle.segments", f"must be a list of 1-{MAX_SEGMENTS} segments")
    shapes = [_segment(row, index, limits) for index, row in enumerate(rows)]
    step_bytes = layout.values * _width(limits)
    if len(code_bytes) != sum(steps for _, _, steps in shapes) * step_bytes:
        raise HandleError("handle.segments", f"the steps add up to {sum(s for _, _, s in shapes)} but the handle "
                                             f"holds {len(code_bytes) / step_bytes:g} steps of codes")
    all_codes = np.frombuffer(code_bytes, dtype="<u2" if _width(limits) == 2 else "<u4").astype(np.int64) + layout.low
    segments, start = [], 0
    for index, (text, duration, steps) in enumerate(shapes):
        codes = all_codes[start:start + steps * layout.values].reshape(steps, *layout.shape)
        start += steps * layout.values
        bad = np.flatnonzero(layout.out_of_range(codes))
        if bad.size:
            raise HandleError(f"handle.segments.{index}.codes", f"step {int(bad[0])} holds a code outside the "
                                                                f"codebook (bounds {list(layout.bounds)})")
        segments.append(HandleSegment(text, duration, codes))
    total = sum(s.duration if s.duration is not None else len(s.codes) * limits.frames_per_token / limits.fps
                for s in segments)
    if total > MAX_TOTAL_S + 1e-9:
        raise HandleError("handle.segments", f"total duration {total:g} s exceeds {MAX_TOTAL_S:g} s")
    return MotionHandle(meta["model"], meta["version"], seed, guidance, temperature, top_k, segments)


def _segment(row: Any, index: int, limits: ModelLimits) -> tuple[str, float | None, int]:
    """(text, duration, steps) of the handle's segment `index`, checked like a request's segment."""
    where = f"handle.segments.{index}"
    if not isinstance(row, dict) or sorted(row) != sorted(SEGMENT_KEYS):
        raise HandleError(where, f"must have exactly the keys {', '.join(SEGMENT_KEYS)}")
    text, duration, steps = row["text"], row["duration"], row["steps"]
    if not isinstance(text, str) or not text.strip() or len(text) > MAX_TEXT_CHARS or text != text.strip():
        raise HandleError(f"{where}.text", f"must be 1-{MAX_TEXT_CHARS} characters, trimmed")
    if isinstance(steps, bool) or not isinstance(steps, int) or not 1 <= steps <= limits.max_tokens:
        raise HandleError(f"{where}.steps", f"must be 1..{limits.max_tokens} (max_tokens), got {steps!r}")
    if duration is None:
        return text, None, steps
    if isinstance(duration, bool) or not isinstance(duration, (int, float)) or not (
            MIN_DURATION_S <= duration <= MAX_DURATION_S):
        raise HandleError(f"{where}.duration", f"must be null or {MIN_DURATION_S}-{MAX_DURATION_S} s, "
                                               f"got {duration!r}")
    expected = tokens_for_duration(float(duration), limits.fps, limits.frames_per_token)
    if steps != expected:
        raise HandleError(f"{where}.steps", f"{steps} steps for {duration:g} s; this model makes {expected}")
    return text, float(duration), steps
