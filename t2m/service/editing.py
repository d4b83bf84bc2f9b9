"""An edit of a handle's motion planned as requests: which segments keep their codes, which are sampled and how.

`plan_edit` checks the edits of a POST /edit body against the handle and the model (the kinds its family declares,
segment indices, durations against max_tokens, the segment count and total duration of the result) and returns the
resulting segments in order plus the sampling requests: one request per regenerated segment (that segment alone,
with its own seed: given, or derived from the handle's seed and its index) and one per continue op (its segments
together, with its seed), each with the handle's options (guidance, temperature, top_k). The route runs the
requests through the model's batcher as any generation, then decodes all the codes once (OnnxEngine.compose).
A failure is an EditError with the `loc` of the field (pydantic's shape: a 422). `edit_in_process` does the same
with an engine directly (`t2m edit`, benchmarks/edit_latency.py).
"""
from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from t2m.service.engine.types import GenerationRequest, ModelLimits, Motion, SegmentRequest, tokens_for_duration
from t2m.service.handles import MotionHandle, make_handle, read_handle, segment_seed
from t2m.service.schemas import MAX_SEGMENTS, MAX_TOTAL_S, ContinueEdit, RegenerateEdit

__all__ = ["EditError", "EditPlan", "EditResult", "PlannedSegment", "SampledPart", "edit_in_process", "plan_edit"]


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

    def field_of(self, part: int, message: str) -> tuple[Any, ...]:
        """The body field a sampled part's error names ("segments.0.text: ..." of its request -> the edit's)."""
        match = re.match(r"segments\.(\d+)\.(\w+)", message)
        edit = self.parts[part].edit
        if match is None:
            return ("body", "edits", edit)
        if self.parts[part].continued:
            return ("body", "edits", edit, "segments", int(match[1]), match[2])
        return ("body", "edits", edit, match[2])


def _check_kind(kind: str, index: int, limits: ModelLimits) -> None:
    if kind in limits.edits:
        return
    family = limits.details.get("family", "?")
    supported = ", ".join(sorted(limits.edits)) or "none yet"
    raise EditError(("body", "edits", index, "op"), f"model {limits.name!r} (family {family!r}) cannot "
                    f"{kind} {'a segment' if kind == 'regenerate' else 'segments'}: the edits it supports are "
                    f"{supported}", kind)


def _steps_within(duration: float | None, loc: tuple[Any, ...], limits: ModelLimits) -> None:
    """A new duration's steps fit the model; a null duration is the model's to end (when it can)."""
    if duration is None:
        if not limits.null_duration:
            raise EditError(loc, f"model {limits.name!r} cannot end a segment itself; give a duration", None)
        return
    steps = tokens_for_duration(duration, limits.fps, limits.frames_per_token)
    if steps > limits.max_tokens:
        raise EditError(loc, f"duration {duration:g} s needs {steps} tokens; this model makes at most "
                             f"{limits.max_tokens} per segment ({limits.max_segment_seconds:g} s)", duration)


def plan_edit(handle: MotionHandle, edits: Sequence[RegenerateEdit | ContinueEdit],
              limits: ModelLimits) -> EditPlan:
    """The edited motion's segments and what to sample (see the module's docstring), or an EditError."""
    plan = EditPlan([PlannedSegment(s.text, s.duration, s.codes) for s in handle.segments])
    before: list[PlannedSegment] = []
    after: list[PlannedSegment] = []
    seen: set[int] = set()
    for index, edit in enumerate(edits):
        if isinstance(edit, RegenerateEdit):
            _check_kind("regenerate", index, limits)
            if edit.segment >= len(handle.segments):
                raise EditError(("body", "edits", index, "segment"), f"the handle has {len(handle.segments)} "
                                f"segments (0..{len(handle.segments) - 1})", edit.segment)
            if edit.segment in seen:
                raise EditError(("body", "edits", index, "segment"), f"segment {edit.segment} is edited twice",
                                edit.segment)
            seen.add(edit.segment)
            old = handle.segments[edit.segment]
            text = edit.text if edit.text is not None else old.text
            duration = edit.duration if edit.duration is not None else old.duration
            if edit.duration is not None:
                _steps_within(duration, ("body", "edits", index, "duration"), limits)
            seed = edit.seed if edit.seed is not None else segment_seed(handle.seed, edit.segment)
            plan.parts.append(SampledPart(index, handle.request([SegmentRequest(text, duration)], seed), False))
            plan.segments[edit.segment] = PlannedSegment(text, duration, part=len(plan.parts) - 1)
            continue
        _check_kind(edit.op, index, limits)
        for j, segment in enumerate(edit.segments):
            _steps_within(segment.duration, ("body", "edits", index, "segments", j, "duration"), limits)
        seed = edit.seed if edit.seed is not None else segment_seed(handle.seed, edit.op)
        requests = [SegmentRequest(s.text, s.duration) for s in edit.segments]
        plan.parts.append(SampledPart(index, handle.request(requests, seed), True))
        added = [PlannedSegment(s.text, s.duration, part=len(plan.parts) - 1, index=j)
                 for j, s in enumerate(requests)]
        (before if edit.op == "prepend" else after).extend(added)
    plan.segments = before + plan.segments + after
    if len(plan.segments) > MAX_SEGMENTS:
        raise EditError(("body", "edits"), f"the edited motion would have {len(plan.segments)} segments, more than "
                                           f"{MAX_SEGMENTS}")
    total = sum(s.duration if s.duration is not None else (
        len(s.codes) * limits.frames_per_token / limits.fps if s.codes is not None else limits.max_segment_seconds)
        for s in plan.segments)
    if total > MAX_TOTAL_S + 1e-9:
        raise EditError(("body", "edits"), f"the edited motion would last {total:g} s, more than {MAX_TOTAL_S:g} s "
                                           "(a null duration to sample counts as the model's longest segment)")
    return plan


@dataclass
class EditResult:
    motion: Motion
    handle: str | None
    edited: list[tuple[int, int]]


def edit_in_process(engine: Any, handle: str, edits: Sequence[RegenerateEdit | ContinueEdit]) -> EditResult:
    """An edit with an OnnxEngine directly, as POST /edit makes it (parts sampled one after the other instead of
    through the queue: the same codes, each request drawing from its own generator). HandleError / EditError /
    RequestLimitError as the route's 422s."""
    limits = engine.limits
    kept = read_handle(handle, limits)
    plan = plan_edit(kept, edits, limits)
    sampled = [engine.generate(part.request) for part in plan.parts]
    request = plan.request(kept)
    motion = engine.compose(request, plan.codes([m.codes or [] for m in sampled]))
    motion.warnings = plan.warnings(sampled, motion)
    return EditResult(motion, make_handle(limits, request, motion.codes), plan.edited())
