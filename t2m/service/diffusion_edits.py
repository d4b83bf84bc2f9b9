"""POST /edit for the diffusion family (MDM, DiP): edits made on normalised feature frames by the family's own
inpainting (known x0 values imposed at every step: t2m.decoding.diffusion), answered with a new recipe handle.

A recipe (service/recipes.py) is replayed: its request generated again (the same frames, bit for bit), then each
recorded edit request applied in order. An edit request's edits name the segments of the motion it is made on:
its body_part edits are applied first (each on its own segment), then its in_between edits from the last gap to the
first (so the indices hold). Every edit draws from its own generator (its seed: given, or derived from the handle's
seed and where it is, as for the token families), so the result is the same on every replica.

- in_between after segment i (a new segment of round(duration * fps) frames, its text): MDM: one window [up to
  CONTEXT_FRAMES known frames before | the new frames | up to CONTEXT_FRAMES known frames after], cut to max_tokens
  taking context from the longer side first; DiP: calls of pred_len frames after the context_len frames before the
  gap (the bundle's standing pose before the first frame), over the new frames then up to context_len known frames
  of the motion after the gap imposed at the end of the predicted frames (so the calls lead into it), split into
  as many calls as needed; only the new frames are kept.
- body_part on segment i (a part, over start..end seconds of it, a text): the part's feature channels over the span
  made anew, every other channel known. MDM: the window is the whole segment (the rows outside the span are all
  known); DiP: calls over the span after the context_len frames before it.

Guarantees: every kept segment's frames are the handle's, bit for bit (a body_part edit's known channels too), so
after decoding the frames before the edit are identical and the ones after it the same motion rigidly moved (the
root's path is a running sum of its velocities).
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from t2m.service.edit_context import context_sides
from t2m.service.editing import AnyEdit, EditError, EditResult, _check_kind
from t2m.service.engine.types import GenerationRequest, ModelLimits, RequestLimitError, SegmentRequest
from t2m.service.handles import HandleError, segment_seed
from t2m.service.recipes import MAX_EDIT_STEPS, Recipe, make_recipe, read_recipe
from t2m.service.schemas import MAX_SEGMENTS, MAX_TOTAL_S, BodyPartEdit, InBetweenEdit

__all__ = ["CONTEXT_FRAMES", "FrameSegment", "edit_recipe", "replay"]

CONTEXT_FRAMES = 20   # MDM in_between: known frames on each side of the new ones (1 s at 20 fps)


@dataclass(frozen=True)
class FrameSegment:
    text: str
    duration: float
    frames: np.ndarray          # normalised [n, F]


def _job(engine: Any, text: str, duration: float, seed: int, guidance: float, loc: tuple[Any, ...]) -> Any:
    """The text encoded and a generator seeded: a one-segment DiffusionRequest; a limit broken is an EditError."""
    request = GenerationRequest([SegmentRequest(text, duration)], seed=seed, guidance=guidance)
    try:
        return engine.codes.job(request, engine.text, engine.limits)
    except RequestLimitError as error:
        raise EditError((*loc, "duration"), str(error).split(": ", 1)[-1], duration) from None


def _body_part(engine: Any, segments: list[FrameSegment], edit: BodyPartEdit, guidance: float,
               loc: tuple[Any, ...]) -> FrameSegment:
    limits: ModelLimits = engine.limits
    old = segments[edit.segment]
    channels = limits.body_parts.get(edit.part)
    if not channels:
        raise EditError((*loc, "part"), f"model {limits.name!r} has no feature channels for {edit.part!r}: its "
                                        f"parts are {', '.join(sorted(limits.body_parts)) or 'none'}", edit.part)
    frames = len(old.frames)
    first = 0 if edit.start is None else math.floor(edit.start * limits.fps)
    last = frames if edit.end is None else min(frames, math.ceil(edit.end * limits.fps))
    if last <= first:
        raise EditError((*loc, "end" if edit.end is not None else "start"),
                        f"the span {edit.start or 0:g}-{edit.end if edit.end is not None else 'end'} s holds no frame "
                        f"of segment {edit.segment} ({frames} frames at {limits.fps} fps)", edit.end)
    text = edit.text if edit.text is not None else old.text
    assert edit.seed is not None
    job = _job(engine, text, old.duration, edit.seed, guidance, loc)
    known = np.ones_like(old.frames, dtype=bool)
    known[first:last, list(channels)] = False
    codes = engine.codes
    new = old.frames.copy()
    if codes.settings.chained:    # DiP: calls over the span, after the frames before it
        before = np.concatenate([*(s.frames for s in segments[:edit.segment]), old.frames[:first]])
        new[first:last] = codes.inpaint(job, old.frames[first:last], known[first:last], codes.prefix_before(before))
    else:                         # MDM: the whole segment, the rows outside the span all known
        new = codes.inpaint(job, old.frames, known)
    return FrameSegment(text, old.duration, new)


def _in_between(engine: Any, segments: list[FrameSegment], edit: InBetweenEdit, guidance: float,
                loc: tuple[Any, ...]) -> FrameSegment:
    assert edit.seed is not None
    job = _job(engine, edit.text, edit.duration, edit.seed, guidance, loc)
    frames = job.frames[0]
    before = np.concatenate([s.frames for s in segments[:edit.after + 1]])
    after = np.concatenate([s.frames for s in segments[edit.after + 1:]])
    codes = engine.codes
    features = before.shape[1]
    if codes.settings.chained:    # DiP: from the frames before; the first frames after imposed at the end
        tail = min(codes.settings.context_len, len(after))
        known = np.concatenate([np.zeros((frames, features), np.float32), after[:tail]])
        mask = np.arange(len(known))[:, None] >= frames
        made = codes.inpaint(job, known, mask, codes.prefix_before(before))
        return FrameSegment(edit.text, edit.duration, made[:frames])
    left, right = context_sides(len(before), len(after), engine.limits.max_tokens - frames, CONTEXT_FRAMES)
    known = np.concatenate([before[len(before) - left:], np.zeros((frames, features), np.float32), after[:right]])
    rows = np.arange(len(known))[:, None]
    made = codes.inpaint(job, known, (rows < left) | (rows >= left + frames))
    return FrameSegment(edit.text, edit.duration, made[left:left + frames])


def _resolved(edit: AnyEdit, seed: int) -> AnyEdit:
    """The edit with its seed given (a derived one: from the handle's seed and where it is, as for the token
    families)."""
    if edit.seed is not None:
        return edit
    where = (f"in_between.{edit.after}" if isinstance(edit, InBetweenEdit)
             else f"body_part.{edit.segment}" if isinstance(edit, BodyPartEdit) else edit.op)
    return edit.model_copy(update={"seed": segment_seed(seed, where)})


def apply_edits(engine: Any, segments: list[FrameSegment], edits: Sequence[AnyEdit], seed: int, guidance: float,
                loc: tuple[Any, ...] = ("body", "edits")) -> tuple[list[FrameSegment], list[AnyEdit],
                                                                   list[tuple[int, int]]]:
    """One edit request on the motion's segments: (the edited segments, the edits with their seeds, (index in the
    edited motion, seed) of every segment made), or an EditError at `loc` + the edit's index and field."""
    limits: ModelLimits = engine.limits
    resolved = []
    seen: set[int] = set()
    gaps: set[int] = set()
    for index, edit in enumerate(edits):
        try:
            _check_kind(edit.op, index, limits)
        except EditError as error:
            raise EditError((*loc, index, "op"), str(error), edit.op) from None
        if isinstance(edit, BodyPartEdit):
            if edit.segment >= len(segments) or edit.segment in seen:
                why = (f"segment {edit.segment} is edited twice" if edit.segment in seen else
                       f"the motion has {len(segments)} segments (0..{len(segments) - 1})")
                raise EditError((*loc, index, "segment"), why, edit.segment)
            seen.add(edit.segment)
        elif isinstance(edit, InBetweenEdit):
            if edit.after >= len(segments) - 1 or edit.after in gaps:
                why = (f"the gap after segment {edit.after} is filled twice" if edit.after in gaps else
                       f"the gap after segment {edit.after} needs a segment after it: the motion has {len(segments)} "
                       f"(after: 0..{len(segments) - 2})")
                raise EditError((*loc, index, "after"), why, edit.after)
            gaps.add(edit.after)
        resolved.append(_resolved(edit, seed))
    if len(segments) + len(gaps) > MAX_SEGMENTS:
        raise EditError(loc, f"the edited motion would have {len(segments) + len(gaps)} segments, more than "
                             f"{MAX_SEGMENTS}")
    total = sum(s.duration for s in segments) + sum(e.duration for e in resolved if isinstance(e, InBetweenEdit))
    if total > MAX_TOTAL_S + 1e-9:
        raise EditError(loc, f"the edited motion would last {total:g} s, more than {MAX_TOTAL_S:g} s")
    out = list(segments)
    made: dict[int, int] = {}
    for index, edit in enumerate(resolved):
        if isinstance(edit, BodyPartEdit):
            out[edit.segment] = _body_part(engine, out, edit, guidance, (*loc, index))
            made[edit.segment] = int(edit.seed)   # type: ignore[arg-type]
    inserted = sorted(((e.after, i, e) for i, e in enumerate(resolved) if isinstance(e, InBetweenEdit)),
                      key=lambda item: -item[0])
    for after, index, edit in inserted:
        out.insert(after + 1, _in_between(engine, out, edit, guidance, (*loc, index)))
    # indices in the edited motion: a body-part segment moves by the gaps filled before it
    edited = [(segment + sum(1 for a, _, _ in inserted if a < segment), seed_) for segment, seed_ in made.items()]
    edited += [(after + 1 + sum(1 for a, _, _ in inserted if a < after), int(e.seed))  # type: ignore[arg-type]
               for after, _, e in inserted]
    return out, resolved, sorted(edited)


def replay(engine: Any, recipe: Recipe) -> tuple[list[FrameSegment], list[tuple[int, int]]]:
    """The recipe's motion as segments of normalised frames (and the last edit request's made segments): its
    request generated, then its edits applied in order; an edit that does not fit is a HandleError naming it."""
    motion = engine.generate(recipe.request())
    assert motion.codes is not None
    segments = [FrameSegment(s.text, float(s.duration or 0.0), np.asarray(frames, np.float32))
                for s, frames in zip(recipe.segments, motion.codes)]
    edited: list[tuple[int, int]] = []
    for step, edits in enumerate(recipe.edits):
        try:
            segments, _, edited = apply_edits(engine, segments, edits, recipe.seed, recipe.guidance,
                                              ("handle", "edits", step))
        except EditError as error:
            raise HandleError(".".join(str(part) for part in error.loc), str(error)) from None
    return segments, edited


def edit_recipe(engine: Any, handle: str | Recipe, edits: Sequence[AnyEdit]) -> EditResult:
    """A diffusion model's edit (POST /edit, `t2m edit`): the handle's motion replayed, the edits applied, decoded
    once and answered with the recipe that records them. HandleError / EditError as the route's 422s."""
    limits: ModelLimits = engine.limits
    recipe = handle if isinstance(handle, Recipe) else read_recipe(handle, limits)
    if edits and len(recipe.edits) >= MAX_EDIT_STEPS:
        raise EditError(("body", "edits"), f"the handle already records {len(recipe.edits)} edit requests, the most "
                                           f"a diffusion handle holds ({MAX_EDIT_STEPS}): start from /generate")
    segments, edited = replay(engine, recipe)
    steps = list(recipe.edits)
    if edits:
        segments, resolved, edited = apply_edits(engine, segments, edits, recipe.seed, recipe.guidance)
        steps.append(resolved)
    else:
        edited = []
    request = GenerationRequest([SegmentRequest(s.text, s.duration) for s in segments], seed=recipe.seed,
                                guidance=recipe.guidance)
    motion = engine.compose(request, [s.frames for s in segments])
    motion.handle = make_recipe(limits, recipe.request(), steps)
    return EditResult(motion, motion.handle, edited)
