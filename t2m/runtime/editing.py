"""An edit of a handle's motion planned as requests: which segments keep their codes, which are sampled and how.

`plan_edit` checks the edits of a POST /edit body against the handle and the model (the kinds its family declares,
segment indices, durations against max_tokens, the segment count and total duration of the result) and returns the
resulting segments in order plus the sampling requests: one request per regenerated segment (that segment alone,
with its own seed: given, or derived from the handle's seed and its index), one per continue op (its segments
together, with its seed), one per in-between or body-part edit, each with the handle's options (guidance,
temperature, top_k). For a family whose loop inpaints (`limits.inpaints`: the masked family) each sampled segment's
request also carries its map with the kept codes around it (service/edit_context.py), so the loop fills it with both
sides as context; the other families sample it alone. The route runs the requests through the model's batcher as
any generation, then decodes all the codes once (OnnxEngine.compose). A failure is an EditError with the `loc` of
the field (pydantic's shape: a 422). `edit_in_process` does the same with an engine directly (`t2m edit`,
t2m/bench/edit_latency.py).
"""
from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from t2m.api import BodyPartEdit, ContinueEdit, InBetweenEdit, RegenerateEdit
from t2m.runtime.edit_context import inpaint_map
from t2m.runtime.handles import MotionHandle, make_handle, read_handle, segment_seed
from t2m.runtime.limits import MAX_SEGMENTS, MAX_TOTAL_S
from t2m.runtime.types import (
    ComposingEngine,
    GenerationRequest,
    ModelLimits,
    Motion,
    RequestLimitError,
    SegmentRequest,
    tokens_for_duration,
)

__all__ = ["AnyEdit", "EditError", "EditPlan", "EditResult", "PlannedSegment", "SampledPart", "edit_in_process",
           "plan_edit"]

AnyEdit = RegenerateEdit | ContinueEdit | InBetweenEdit | BodyPartEdit
INPAINTED = frozenset({"in_between", "body_part"})   # kinds only a family whose loop inpaints can make


class EditError(ValueError):
    """An edit that cannot be made; `loc` names the field ("body", "edits", 0, "segment")."""

    def __init__(self, loc: tuple[Any, ...], message: str, value: Any = None) -> None:
        super().__init__(message)
        self.loc, self.value = loc, value

    def error(self) -> dict[str, Any]:
        return {"type": "value_error", "loc": self.loc, "msg": str(self), "input": self.value}


@dataclass
class PlannedSegment:
    """A segment of the edited motion: its text and duration, and its codes (kept from the handle, or filled in
    from the sampled part `part`, its `index`-th segment)."""

    text: str
    duration: float | None
    codes: np.ndarray | None = None
    part: int | None = None
    index: int = 0
    steps: int | None = None            # a sampled segment's steps when its duration is null (kept from the handle)
    base: np.ndarray | None = None      # body_part: the segment's old codes, kept outside `fill`
    fill: np.ndarray | None = None      # body_part: bool [steps, C], the tokens to sample again


@dataclass
class SampledPart:
    """A request to sample: the `edit`-th edit's segments (a regenerate edit: one; a continue op: its own)."""

    edit: int
    request: GenerationRequest
    continued: bool


@dataclass
class EditPlan:
    segments: list[PlannedSegment]
    parts: list[SampledPart] = field(default_factory=list)

    def request(self, handle: MotionHandle) -> GenerationRequest:
        """The whole edited motion as a request (what its answer's handle records): the handle's options."""
        return handle.request([SegmentRequest(s.text, s.duration) for s in self.segments])

    def codes(self, sampled: Sequence[Sequence[np.ndarray]]) -> list[np.ndarray]:
        """Every segment's codes, the sampled parts' (`sampled[p]`: part p's segments' codes) filled in."""
        return [np.asarray(sampled[s.part][s.index] if s.part is not None else s.codes) for s in self.segments]

    def edited(self) -> list[tuple[int, int]]:
        """(index in the edited motion, seed) of every sampled segment."""
        return [(i, self.parts[s.part].request.seed) for i, s in enumerate(self.segments) if s.part is not None]

    def warnings(self, sampled: Sequence[Motion], motion: Motion) -> list[str]:
        """The sampled parts' warnings, their segment numbers the edited motion's, then the decode's; once each."""
        out: list[str] = []
        for part, sub in enumerate(sampled):
            indices = [i for i, s in enumerate(self.segments) if s.part == part]

            def renumber(match: re.Match[str], indices: list[int] = indices) -> str:
                return f"segments.{indices[int(match[1])]}."

            out += [re.sub(r"^segments\.(\d+)\.", renumber, warning) for warning in sub.warnings]
        return list(dict.fromkeys([*out, *motion.warnings]))

    def field_of(self, part: int, error: RequestLimitError) -> tuple[Any, ...]:
        """The body field a sampled part's error is about (its request's "segments.0.text" -> the edit's)."""
        edit = self.parts[part].edit
        where = error.location
        if len(where) != 3 or where[0] != "segments":
            return ("body", "edits", edit)
        if self.parts[part].continued:
            return ("body", "edits", edit, *where[1:])
        return ("body", "edits", edit, where[2])


_WHAT = {"regenerate": "regenerate a segment", "append": "append segments", "prepend": "prepend segments",
         "in_between": "fill a gap between segments (in_between)", "body_part": "regenerate a body part (body_part)"}


def check_edit_kind(kind: str, index: int, limits: ModelLimits) -> None:
    """The model's family declares the kind (and, for the inpainted kinds, its loop inpaints); else a 422 at `op`."""
    if kind in limits.edits and (kind not in INPAINTED or limits.inpaints):
        return
    family = limits.details.get("family", "?")
    supported = ", ".join(sorted(k for k in limits.edits if k not in INPAINTED or limits.inpaints)) or "none yet"
    raise EditError(("body", "edits", index, "op"), f"model {limits.name!r} (family {family!r}) cannot "
                    f"{_WHAT[kind]}: the edits it supports are {supported}", kind)


def _steps_within(duration: float | None, loc: tuple[Any, ...], limits: ModelLimits) -> None:
    """A new duration's steps fit the model; a null duration is the model's to end (when it can, and not in an
    inpainted map, whose rows are fixed before sampling)."""
    if duration is None:
        if not limits.null_duration or limits.inpaints:
            why = ("cannot end a segment itself" if not limits.null_duration
                   else "fills a new segment between kept codes")
            raise EditError(loc, f"model {limits.name!r} {why}; give a duration", None)
        return
    steps = tokens_for_duration(duration, limits.fps, limits.frames_per_token)
    if steps > limits.max_tokens:
        raise EditError(loc, f"duration {duration:g} s needs {steps} tokens; this model makes at most "
                             f"{limits.max_tokens} per segment ({limits.max_segment_seconds:g} s)", duration)


def _segment_index(value: int, loc: tuple[Any, ...], handle: MotionHandle, seen: set[int]) -> None:
    """A segment of the handle, edited once."""
    if value >= len(handle.segments):
        raise EditError(loc, f"the handle has {len(handle.segments)} segments (0..{len(handle.segments) - 1})", value)
    if value in seen:
        raise EditError(loc, f"segment {value} is edited twice", value)
    seen.add(value)


def _body_fill(edit: BodyPartEdit, index: int, codes: np.ndarray, limits: ModelLimits) -> np.ndarray:
    """bool [steps, C]: the part's columns over the edit's span of the segment (`start` .. `end` s, whole rows)."""
    columns = limits.body_parts.get(edit.part)
    if not columns:
        raise EditError(("body", "edits", index, "part"), f"model {limits.name!r} has no token columns for "
                        f"{edit.part!r}: its parts are {', '.join(sorted(limits.body_parts)) or 'none'}", edit.part)
    rate = limits.fps / limits.frames_per_token
    first = 0 if edit.start is None else math.floor(edit.start * rate)
    last = len(codes) if edit.end is None else min(len(codes), math.ceil(edit.end * rate))
    if last <= first:
        raise EditError(("body", "edits", index, "end" if edit.end is not None else "start"),
                        f"the span {edit.start or 0:g}-{edit.end if edit.end is not None else 'end'} s holds no code "
                        f"step of segment {edit.segment} ({len(codes)} steps of {1 / rate:g} s)", edit.end)
    fill = np.zeros(codes.shape[:2], dtype=bool)
    fill[first:last, list(columns)] = True
    return fill


def plan_edit(handle: MotionHandle, edits: Sequence[AnyEdit], limits: ModelLimits) -> EditPlan:
    """The edited motion's segments and what to sample (see the module's docstring), or an EditError."""
    plan = EditPlan([PlannedSegment(s.text, s.duration, s.codes) for s in handle.segments])
    before: list[PlannedSegment] = []
    after: list[PlannedSegment] = []
    between: dict[int, PlannedSegment] = {}
    seen: set[int] = set()
    for index, edit in enumerate(edits):
        check_edit_kind(edit.op, index, limits)
        if isinstance(edit, (RegenerateEdit, BodyPartEdit)):
            _segment_index(edit.segment, ("body", "edits", index, "segment"), handle, seen)
            old = handle.segments[edit.segment]
            text = edit.text if edit.text is not None else old.text
            duration = old.duration
            # an inpainting family keeps a null-duration segment's rows; the others let the model end it again
            planned = PlannedSegment(text, duration, steps=len(old.codes) if limits.inpaints else None)
            if isinstance(edit, BodyPartEdit):
                planned.base, planned.fill = old.codes, _body_fill(edit, index, old.codes, limits)
                where: int | str = f"body_part.{edit.segment}"
            else:
                where = edit.segment
                if edit.duration is not None:
                    _steps_within(edit.duration, ("body", "edits", index, "duration"), limits)
                    planned.duration, planned.steps = edit.duration, None
            seed = edit.seed if edit.seed is not None else segment_seed(handle.seed, where)
            plan.parts.append(SampledPart(index, handle.request([SegmentRequest(text, planned.duration)], seed),
                                          False))
            planned.part = len(plan.parts) - 1
            plan.segments[edit.segment] = planned
            continue
        if isinstance(edit, InBetweenEdit):
            if edit.after >= len(handle.segments) - 1:
                raise EditError(("body", "edits", index, "after"), f"the gap after segment {edit.after} needs a "
                                f"segment after it: the handle has {len(handle.segments)} (after: 0.."
                                f"{len(handle.segments) - 2})", edit.after)
            if edit.after in between:
                raise EditError(("body", "edits", index, "after"), f"the gap after segment {edit.after} is filled "
                                                                   "twice", edit.after)
            _steps_within(edit.duration, ("body", "edits", index, "duration"), limits)
            seed = edit.seed if edit.seed is not None else segment_seed(handle.seed, f"in_between.{edit.after}")
            plan.parts.append(SampledPart(index, handle.request([SegmentRequest(edit.text, edit.duration)], seed),
                                          False))
            between[edit.after] = PlannedSegment(edit.text, edit.duration, part=len(plan.parts) - 1)
            continue
        for j, segment in enumerate(edit.segments):
            _steps_within(segment.duration, ("body", "edits", index, "segments", j, "duration"), limits)
        seed = edit.seed if edit.seed is not None else segment_seed(handle.seed, edit.op)
        requests = [SegmentRequest(s.text, s.duration) for s in edit.segments]
        plan.parts.append(SampledPart(index, handle.request(requests, seed), True))
        added = [PlannedSegment(s.text, s.duration, part=len(plan.parts) - 1, index=j)
                 for j, s in enumerate(requests)]
        (before if edit.op == "prepend" else after).extend(added)
    middle = [s for i, planned in enumerate(plan.segments)
              for s in ([planned, between[i]] if i in between else [planned])]
    plan.segments = before + middle + after
    if len(plan.segments) > MAX_SEGMENTS:
        raise EditError(("body", "edits"), f"the edited motion would have {len(plan.segments)} segments, more than "
                                           f"{MAX_SEGMENTS}")
    total = sum(_seconds(s, limits) for s in plan.segments)
    if total > MAX_TOTAL_S + 1e-9:
        raise EditError(("body", "edits"), f"the edited motion would last {total:g} s, more than {MAX_TOTAL_S:g} s "
                                           "(a null duration to sample counts as the model's longest segment)")
    if limits.inpaints:
        _add_context(plan, limits)
    return plan


def _seconds(segment: PlannedSegment, limits: ModelLimits) -> float:
    """A planned segment's length in seconds (a null duration: its steps' decoded length, or the longest segment)."""
    if segment.duration is not None:
        return segment.duration
    steps = len(segment.codes) if segment.codes is not None else segment.steps
    return limits.max_segment_seconds if steps is None else steps * limits.frames_per_token / limits.fps


def _add_context(plan: EditPlan, limits: ModelLimits) -> None:
    """Each part's request with its segments' inpainting maps: the kept codes around them (edit_context.py)."""
    assert limits.codes is not None
    shape = limits.codes.shape
    maps: dict[int, list[Any]] = {p: [None] * len(part.request.segments) for p, part in enumerate(plan.parts)}
    for position, segment in enumerate(plan.segments):
        if segment.part is None:
            continue
        steps = segment.steps if segment.duration is None else tokens_for_duration(
            segment.duration, limits.fps, limits.frames_per_token)
        assert steps is not None
        own = segment.base if segment.base is not None else np.zeros((steps, *shape), dtype=np.int64)
        fill = segment.fill if segment.fill is not None else np.ones((steps, shape[0]), dtype=bool)
        maps[segment.part][segment.index] = inpaint_map(plan.segments, position, own, fill, limits.max_tokens)
    for p, part in enumerate(plan.parts):
        part.request = replace(part.request, inpaint=tuple(maps[p]))


@dataclass
class EditResult:
    motion: Motion
    handle: str | None
    edited: list[tuple[int, int]]


def finish_edit(engine: ComposingEngine, kept: MotionHandle, plan: EditPlan, sampled: Sequence[Motion]) -> EditResult:
    """An edit of a handle's codes from its sampled parts (however they were sampled: in process, or through the
    model's batcher by POST /edit): every segment's codes in order, decoded once, the parts' warnings, the new
    handle. The one place such an edit is put together."""
    request = plan.request(kept)
    motion = engine.compose(request, plan.codes([m.codes or [] for m in sampled]))
    motion.warnings = plan.warnings(sampled, motion)
    motion.handle = make_handle(engine.limits, request, motion.codes)
    return EditResult(motion, motion.handle, plan.edited())


def edit_in_process(engine: Any, handle: str | MotionHandle, edits: Sequence[AnyEdit]) -> EditResult:
    """An edit with an OnnxEngine directly, as POST /edit makes it (parts sampled one after the other instead of
    through the queue: the same codes, each request drawing from its own generator); `handle` a handle string or
    one already read (an uploaded motion's: t2m/runtime/uploads.py). HandleError / EditError / RequestLimitError as
    the route's 422s."""
    kept = handle if isinstance(handle, MotionHandle) else read_handle(handle, engine.limits)
    plan = plan_edit(kept, edits, engine.limits)
    return finish_edit(engine, kept, plan, [engine.generate(part.request) for part in plan.parts])
