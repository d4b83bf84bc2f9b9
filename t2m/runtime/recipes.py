"""A diffusion answer's handle: a recipe, not codes. The diffusion family's model makes normalised feature frames
itself (no codes to keep), and its motion is a deterministic function of the model (name and version), the seed, the
guidance and each segment's text and duration (sampling is seeded per request and the same whatever shares the
batch), then of each edit made on it with its own seed. So the handle records exactly that, and reading it makes the
frames again, bit for bit (service/diffusion_edits.py replays it).

Format (version 2): `t2m2.` + base64url without padding of `checksum || zlib(body)`:

- body = compact JSON, UTF-8: {"model", "version" (the manifest's), "seed", "guidance" (the request's, resolved),
  "segments": [{"text", "duration"}] (the request as /generate took it), "edits": [[edit, ...], ...]} — each inner
  list one POST /edit's edits, in the order they were made, each as the API takes it (in_between: op, after, text,
  duration, seed; body_part: op, segment, part, text, start, end, seed) with its seed resolved;
- checksum = the first 16 bytes of SHA-256(body), as version 1's (corruption, not a signature).

Bounds: at most MAX_EDIT_STEPS edit requests of at most MAX_SEGMENTS edits each, the body at most MAX_RECIPE_BYTES
(bounded before decompressing), the string at most MAX_RECIPE_CHARS. Reading (`read_recipe`) checks everything as
version 1's reader does: the checksum, the JSON's keys and types, the model's name and version, the seed, the
guidance, each segment (text, duration within the API's limits and the model's longest segment, the total), each
edit against the API's schema (with its seed given); an edit that does not fit the motion it was made on is refused
when it is replayed. Every failure is a HandleError naming the part ("handle.edits.0.1.after"): a 422.
"""
from __future__ import annotations

import base64
import hashlib
import json
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from pydantic import TypeAdapter, ValidationError

from t2m.api import Edit
from t2m.runtime.handle_format import CHECKSUM_BYTES, HandleError, model_seed_guidance, no_constant, unpack_handle
from t2m.runtime.limits import MAX_DURATION_S, MAX_SEGMENTS, MAX_TEXT_CHARS, MAX_TOTAL_S, MIN_DURATION_S
from t2m.runtime.types import GenerationRequest, ModelLimits, SegmentRequest, frames_for_duration

__all__ = ["MAX_EDIT_STEPS", "RECIPE_PREFIX", "Recipe", "make_recipe", "read_recipe", "recipe_model"]

RECIPE_PREFIX = "t2m2."
MAX_EDIT_STEPS = 16                 # edit requests a recipe records (each replayed when it is read)
MAX_RECIPE_BYTES = 256 * 1024       # 32 segments and 16 x 32 edits of 300-character texts, escaped, fit
MAX_RECIPE_CHARS = 4 * MAX_RECIPE_BYTES
RECIPE_KEYS = ("model", "version", "seed", "guidance", "segments", "edits")
SEGMENT_KEYS = ("text", "duration")
_EDIT = TypeAdapter(Edit)


@dataclass(frozen=True)
class Recipe:
    """A read recipe: the model, the request's seed, guidance and segments, and the edit requests made since."""

    model: str
    version: str
    seed: int
    guidance: float
    segments: list[SegmentRequest]
    edits: list[list[Any]] = field(default_factory=list)   # schemas.Edit objects, their seeds given

    def request(self) -> GenerationRequest:
        """The /generate request the recipe starts from."""
        return GenerationRequest(segments=list(self.segments), seed=self.seed, guidance=self.guidance)


def _edit_json(edit: Any) -> dict[str, Any]:
    return edit.model_dump(mode="json") if hasattr(edit, "model_dump") else dict(edit)


def make_recipe(limits: ModelLimits, request: GenerationRequest, edits: Sequence[Sequence[Any]] = ()) -> str:
    """The recipe handle of `request` on the model of `limits`, with the edit requests made on it since."""
    body = {"model": limits.name, "version": limits.version, "seed": int(request.seed),
            "guidance": float(request.guidance),
            "segments": [{"text": s.text, "duration": s.duration} for s in request.segments],
            "edits": [[_edit_json(edit) for edit in step] for step in edits]}
    data = json.dumps(body, separators=(",", ":"), ensure_ascii=False).encode()
    packed = hashlib.sha256(data).digest()[:CHECKSUM_BYTES] + zlib.compress(data, 9)
    return RECIPE_PREFIX + base64.urlsafe_b64encode(packed).rstrip(b"=").decode("ascii")


def _body(handle: str) -> dict[str, Any]:
    """The checked JSON of a recipe string (checksum, size, keys)."""
    checksum, compressed = unpack_handle(handle, RECIPE_PREFIX, MAX_RECIPE_CHARS)
    inflater = zlib.decompressobj()
    try:
        data = inflater.decompress(compressed, MAX_RECIPE_BYTES + 1)
    except zlib.error:
        raise HandleError("handle", "corrupt (its compressed data does not decompress)") from None
    if len(data) > MAX_RECIPE_BYTES or inflater.unconsumed_tail:
        raise HandleError("handle", f"decompresses to more than {MAX_RECIPE_BYTES} bytes, the most a recipe holds")
    if not inflater.eof or inflater.unused_data:
        raise HandleError("handle", "corrupt (truncated, or data after its end)")
    if hashlib.sha256(data).digest()[:CHECKSUM_BYTES] != checksum:
        raise HandleError("handle.checksum", "does not match the handle's content (corrupted or altered)")
    try:
        body = json.loads(data.decode("utf-8"), parse_constant=no_constant)
    except (UnicodeDecodeError, ValueError):
        raise HandleError("handle", "its description is not JSON") from None
    if not isinstance(body, dict) or sorted(body) != sorted(RECIPE_KEYS):
        raise HandleError("handle", f"its description must have exactly the keys {', '.join(RECIPE_KEYS)}")
    if not isinstance(body["model"], str) or not isinstance(body["version"], str):
        raise HandleError("handle.model", "must name a model and its version")
    return body


def recipe_model(handle: str) -> tuple[str, str]:
    """The (name, version) a recipe names (its checksum and keys checked, nothing else yet)."""
    body = _body(handle)
    return body["model"], body["version"]


def _segment(row: Any, index: int, limits: ModelLimits) -> SegmentRequest:
    where = f"handle.segments.{index}"
    if not isinstance(row, dict) or sorted(row) != sorted(SEGMENT_KEYS):
        raise HandleError(where, f"must have exactly the keys {', '.join(SEGMENT_KEYS)}")
    text, duration = row["text"], row["duration"]
    if not isinstance(text, str) or not text.strip() or len(text) > MAX_TEXT_CHARS or text != text.strip():
        raise HandleError(f"{where}.text", f"must be 1-{MAX_TEXT_CHARS} characters, trimmed")
    if isinstance(duration, bool) or not isinstance(duration, (int, float)) or not (
            MIN_DURATION_S <= duration <= MAX_DURATION_S):
        raise HandleError(f"{where}.duration", f"must be {MIN_DURATION_S}-{MAX_DURATION_S} s (a diffusion model "
                                               f"needs every duration), got {duration!r}")
    frames = frames_for_duration(float(duration), limits.fps)
    if frames > limits.max_tokens:
        raise HandleError(f"{where}.duration", f"{duration:g} s is {frames} frames; model {limits.name!r} makes at "
                                               f"most {limits.max_tokens} per segment")
    return SegmentRequest(text, float(duration))


def _edits(steps: Any) -> list[list[Any]]:
    if not isinstance(steps, list) or len(steps) > MAX_EDIT_STEPS:
        raise HandleError("handle.edits", f"must be a list of at most {MAX_EDIT_STEPS} edit requests")
    out = []
    for s, step in enumerate(steps):
        if not isinstance(step, list) or not 1 <= len(step) <= MAX_SEGMENTS:
            raise HandleError(f"handle.edits.{s}", f"must be a list of 1-{MAX_SEGMENTS} edits")
        edits = []
        for k, row in enumerate(step):
            try:
                edit = _EDIT.validate_python(row)
            except ValidationError as error:
                first = error.errors()[0]
                where = ".".join(str(part) for part in (s, k, *first["loc"][1:]))
                raise HandleError(f"handle.edits.{where}", first["msg"]) from None
            if getattr(edit, "seed", None) is None:
                raise HandleError(f"handle.edits.{s}.{k}.seed", "must be given (a recipe records every seed)")
            edits.append(edit)
        out.append(edits)
    return out


def read_recipe(handle: str, limits: ModelLimits) -> Recipe:
    """The recipe checked against the model of `limits` (see the module's docstring), or a HandleError."""
    if not limits.recipe:
        raise HandleError("handle", f"model {limits.name!r} makes token codes: its handles start with 't2m1.'")
    body = _body(handle)
    seed, guidance = model_seed_guidance(body, limits)
    rows = body["segments"]
    if not isinstance(rows, list) or not 1 <= len(rows) <= MAX_SEGMENTS:
        raise HandleError("handle.segments", f"must be a list of 1-{MAX_SEGMENTS} segments")
    segments = [_segment(row, index, limits) for index, row in enumerate(rows)]
    total = sum(s.duration or 0.0 for s in segments)
    if total > MAX_TOTAL_S + 1e-9:
        raise HandleError("handle.segments", f"total duration {total:g} s exceeds {MAX_TOTAL_S:g} s")
    return Recipe(body["model"], body["version"], seed, guidance, segments, _edits(body["edits"]))
