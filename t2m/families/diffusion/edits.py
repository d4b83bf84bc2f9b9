"""POST /edit for the diffusion family (MDM, DiP): edits made on normalised feature frames by the family's own
inpainting (known x0 values imposed at every step: t2m.families.diffusion.loop), answered with a new recipe handle.

A recipe (service/recipes.py) is replayed: its request generated again (the same frames, bit for bit), then each
recorded edit request applied in order. An edit request's edits name the segments of the motion it is made on: its
regenerate and body_part edits are applied first (each on its own segment), then its in_between edits from the last
gap to the first (so the indices hold), then its appends, then its prepends. Every edit draws from its own
generator (its seed: given, or derived from the handle's seed and where it is, as for the token families), so the
result is the same on every replica.

- in_between after segment i (a new segment of round(duration * fps) frames, its text), and regenerate on DiP:
  MDM: one window [up to CONTEXT_FRAMES known frames before | the new frames | up to CONTEXT_FRAMES known frames
  after], cut to max_tokens taking context from the longer side first; DiP: calls of pred_len frames after the
  context_len frames before the gap (the bundle's standing pose before the first frame), over the new frames then
  up to context_len known frames of the motion after the gap imposed at the end of the predicted frames (so the
  calls lead into it), split into as many calls as needed; only the new frames are kept.
- regenerate on MDM, append and prepend on MDM: the new segments made whole (as /generate makes a sentence), then
  their joins with the kept neighbours in-betweened as /generate's joins are (the unconditional model over the
  join windows, engine/diffusion_codes.py `rejoin`): those windows remake up to join_frames kept frames a side.
- append on DiP continues from the last context_len frames as /generate's calls do; prepend starts from the
  standing pose, its last segment leading into the motion's first frames (imposed at its end).
- body_part on segment i (a part, over start..end seconds of it, a text): the part's feature channels over the span
  made anew, every other channel known. MDM: the window is the whole segment (the rows outside the span are all
  known); DiP: calls over the span after the context_len frames before it.

Guarantees: every kept segment's frames are the handle's, bit for bit (a body_part edit's known channels too; on
MDM but for the join windows of a regenerated or added segment), so after decoding the frames before the edit are
identical and the ones after it the same motion rigidly moved (the root's path is a running sum of its velocities).
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from t2m.api import BodyPartEdit, ContinueEdit, InBetweenEdit, RegenerateEdit
from t2m.runtime.edit_context import context_sides
from t2m.runtime.editing import AnyEdit, EditError, EditResult, check_edit_kind
from t2m.runtime.handles import HandleError, segment_seed
from t2m.runtime.limits import MAX_SEGMENTS, MAX_TOTAL_S
from t2m.runtime.recipes import MAX_EDIT_STEPS, Recipe, make_recipe, read_recipe
from t2m.runtime.types import GenerationRequest, ModelLimits, RequestLimitError, SegmentRequest

__all__ = ["CONTEXT_FRAMES", "FrameSegment", "edit_recipe", "replay"]

CONTEXT_FRAMES = 20   # MDM in_between: known frames on each side of the new ones (1 s at 20 fps)


@dataclass(frozen=True)
class FrameSegment:
    text: str
    duration: float
    frames: np.ndarray          # normalised [n, F]


def _job(engine: Any, segments: Sequence[SegmentRequest], seed: int, guidance: float, loc: tuple[Any, ...],
         continued: bool = False) -> Any:
    """The texts encoded and a generator seeded: a DiffusionRequest of these segments (as /generate makes one); a
    limit broken is an EditError naming the edit's field (a continue edit's: its segment's)."""
    request = GenerationRequest(list(segments), seed=seed, guidance=guidance)
    try:
        return engine.codes.job(request, engine.text, engine.limits)
    except RequestLimitError as error:
        field = error.location
        if len(field) != 3 or field[0] != "segments":
            raise EditError(loc, str(error)) from None
        where = (*loc, *field) if continued else (*loc, field[2])
        raise EditError(where, error.why, None) from None


def _concat_frames(parts: Sequence[np.ndarray], features: int) -> np.ndarray:
    """The frames end to end ([0, F] for none)."""
    return np.concatenate([np.zeros((0, features), np.float32), *parts])


def _concat(segments: Sequence[FrameSegment], features: int) -> np.ndarray:
    return _concat_frames([s.frames for s in segments], features)


def _fill(engine: Any, job: Any, segment: int, before: np.ndarray, after: np.ndarray) -> np.ndarray:
    """A new segment (the job's `segment`-th, its frames) between the frames `before` and `after` (either may be
    empty), both kept: MDM one window with up to CONTEXT_FRAMES known frames a side; DiP calls after the frames
    before, the first context_len frames after imposed at the end."""
    codes = engine.codes
    frames, features = job.frames[segment], codes.features
    if codes.settings.chained:
        tail = min(codes.settings.context_len, len(after))
        known = np.concatenate([np.zeros((frames, features), np.float32), after[:tail]])
        mask = np.arange(len(known))[:, None] >= frames
        return codes.inpaint(job, known, mask, codes.prefix_before(before), segment)[:frames]
    left, right = context_sides(len(before), len(after), engine.limits.max_tokens - frames, CONTEXT_FRAMES)
    known = np.concatenate([before[len(before) - left:], np.zeros((frames, features), np.float32), after[:right]])
    rows = np.arange(len(known))[:, None]
    return codes.inpaint(job, known, (rows < left) | (rows >= left + frames), segment=segment)[left:left + frames]


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
    job = _job(engine, [SegmentRequest(text, old.duration)], edit.seed, guidance, loc)
    known = np.ones_like(old.frames, dtype=bool)
    known[first:last, list(channels)] = False
    codes = engine.codes
    new = old.frames.copy()
    if codes.settings.chained:    # DiP: calls over the span, after the frames before it
        before = np.concatenate([_concat(segments[:edit.segment], codes.features), old.frames[:first]])
        new[first:last] = codes.inpaint(job, old.frames[first:last], known[first:last], codes.prefix_before(before))
    else:                         # MDM: the whole segment, the rows outside the span all known
        new = codes.inpaint(job, old.frames, known)
    return FrameSegment(text, old.duration, new)


def _regenerate(engine: Any, segments: list[FrameSegment], edit: RegenerateEdit, guidance: float,
                loc: tuple[Any, ...]) -> list[FrameSegment]:
    """Segment i made again (its text, duration or seed changed). MDM: a whole motion, then its joins with its
    neighbours in-betweened as /generate's are; DiP: from the frames before it, the next segment's first frames
    imposed at its end."""
    old = segments[edit.segment]
    text = edit.text if edit.text is not None else old.text
    duration = edit.duration if edit.duration is not None else old.duration
    assert edit.seed is not None
    job = _job(engine, [SegmentRequest(text, duration)], edit.seed, guidance, loc)
    codes, i = engine.codes, edit.segment
    out = list(segments)
    if codes.settings.chained:
        frames = _fill(engine, job, 0, _concat(segments[:i], codes.features), _concat(segments[i + 1:], codes.features))
        out[i] = FrameSegment(text, duration, frames)
        return out
    out[i] = FrameSegment(text, duration, codes.whole(job)[0])
    return _rejoined(engine, job, out, {i - 1, i})


def _rejoined(engine: Any, job: Any, segments: list[FrameSegment], joins: set[int]) -> list[FrameSegment]:
    """MDM: the segments with the joins in `joins` in-betweened (engine/diffusion_codes.py's rejoin)."""
    parts = engine.codes.rejoin(job, [s.frames for s in segments], joins)
    return [FrameSegment(s.text, s.duration, part) for s, part in zip(segments, parts)]


def _continue(engine: Any, segments: list[FrameSegment], edit: ContinueEdit, guidance: float,
              loc: tuple[Any, ...]) -> list[FrameSegment]:
    """Segments appended (or prepended) as one request with the edit's seed. MDM: each a whole motion, then the
    joins from the old motion's end (to its start) on in-betweened; DiP: append continues from the last frames as
    /generate's calls continue, prepend starts from the standing pose, its last segment leading into the motion's
    first frames (imposed at its end)."""
    requests = [SegmentRequest(s.text, s.duration) for s in edit.segments]
    assert edit.seed is not None
    job = _job(engine, requests, edit.seed, guidance, loc, continued=True)
    codes = engine.codes
    old = _concat(segments, codes.features)
    made: list[np.ndarray] = []
    if not codes.settings.chained:
        made = codes.whole(job)
    for k in range(len(requests) if codes.settings.chained else 0):
        before = _concat_frames([old, *made] if edit.op == "append" else made, codes.features)
        after = old[:0] if edit.op == "append" or k < len(requests) - 1 else old
        made.append(_fill(engine, job, k, before, after))
    new = [FrameSegment(r.text, float(r.duration or 0.0), frames) for r, frames in zip(requests, made)]
    if edit.op == "append":
        out, joins = segments + new, set(range(len(segments) - 1, len(segments) + len(new) - 1))
    else:
        out, joins = new + segments, set(range(len(new)))
    return out if codes.settings.chained else _rejoined(engine, job, out, joins)


def _in_between(engine: Any, segments: list[FrameSegment], edit: InBetweenEdit, guidance: float,
                loc: tuple[Any, ...]) -> FrameSegment:
    assert edit.seed is not None
    job = _job(engine, [SegmentRequest(edit.text, edit.duration)], edit.seed, guidance, loc)
    features = engine.codes.features
    frames = _fill(engine, job, 0, _concat(segments[:edit.after + 1], features),
                   _concat(segments[edit.after + 1:], features))
    return FrameSegment(edit.text, edit.duration, frames)


def _resolved(edit: AnyEdit, seed: int) -> AnyEdit:
    """The edit with its seed given (a derived one: from the handle's seed and where it is, as for the token
    families)."""
    if edit.seed is not None:
        return edit
    where: int | str = (f"in_between.{edit.after}" if isinstance(edit, InBetweenEdit)
                        else f"body_part.{edit.segment}" if isinstance(edit, BodyPartEdit)
                        else edit.segment if isinstance(edit, RegenerateEdit) else edit.op)
    return edit.model_copy(update={"seed": segment_seed(seed, where)})


def _checked(engine: Any, segments: list[FrameSegment], edits: Sequence[AnyEdit], seed: int,
             loc: tuple[Any, ...]) -> list[AnyEdit]:
    """The edits checked against the motion and the model (kinds, indices, the result's size), seeds resolved."""
    limits: ModelLimits = engine.limits
    resolved = []
    seen: set[int] = set()
    gaps: set[int] = set()
    count, total = len(segments), sum(s.duration for s in segments)
    for index, edit in enumerate(edits):
        try:
            check_edit_kind(edit.op, index, limits)
        except EditError as error:
            raise EditError((*loc, index, "op"), str(error), edit.op) from None
        if isinstance(edit, (BodyPartEdit, RegenerateEdit)):
            if edit.segment >= len(segments) or edit.segment in seen:
                why = (f"segment {edit.segment} is edited twice" if edit.segment in seen else
                       f"the motion has {len(segments)} segments (0..{len(segments) - 1})")
                raise EditError((*loc, index, "segment"), why, edit.segment)
            seen.add(edit.segment)
            if isinstance(edit, RegenerateEdit) and edit.duration is not None:
                total += edit.duration - segments[edit.segment].duration
        elif isinstance(edit, InBetweenEdit):
            if edit.after >= len(segments) - 1 or edit.after in gaps:
                why = (f"the gap after segment {edit.after} is filled twice" if edit.after in gaps else
                       f"the gap after segment {edit.after} needs a segment after it: the motion has {len(segments)} "
                       f"(after: 0..{len(segments) - 2})")
                raise EditError((*loc, index, "after"), why, edit.after)
            gaps.add(edit.after)
            count, total = count + 1, total + edit.duration
        else:
            for k, segment in enumerate(edit.segments):
                if segment.duration is None:
                    raise EditError((*loc, index, "segments", k, "duration"), f"model {limits.name!r} has no length "
                                    "estimator; give this segment a duration in seconds", None)
                total += segment.duration
            count += len(edit.segments)
        resolved.append(_resolved(edit, seed))
    if count > MAX_SEGMENTS:
        raise EditError(loc, f"the edited motion would have {count} segments, more than {MAX_SEGMENTS}")
    if total > MAX_TOTAL_S + 1e-9:
        raise EditError(loc, f"the edited motion would last {total:g} s, more than {MAX_TOTAL_S:g} s")
    return resolved


def apply_edits(engine: Any, segments: list[FrameSegment], edits: Sequence[AnyEdit], seed: int, guidance: float,
                loc: tuple[Any, ...] = ("body", "edits")) -> tuple[list[FrameSegment], list[AnyEdit],
                                                                   list[tuple[int, int]]]:
    """One edit request on the motion's segments: (the edited segments, the edits with their seeds, (index in the
    edited motion, seed) of every segment made), or an EditError at `loc` + the edit's index and field. Order:
    regenerate and body_part edits (each its own segment), in_between edits from the last gap back, appends,
    prepends; the indices are the motion's as sent."""
    resolved = _checked(engine, segments, edits, seed, loc)
    out = list(segments)
    seeds: list[int | None] = [None] * len(out)     # the seed of each segment made by this request
    for index, edit in enumerate(resolved):
        if isinstance(edit, BodyPartEdit):
            out[edit.segment] = _body_part(engine, out, edit, guidance, (*loc, index))
        elif isinstance(edit, RegenerateEdit):
            out = _regenerate(engine, out, edit, guidance, (*loc, index))
        else:
            continue
        seeds[edit.segment] = edit.seed
    for index, edit in sorted(((i, e) for i, e in enumerate(resolved) if isinstance(e, InBetweenEdit)),
                              key=lambda item: -item[1].after):
        out.insert(edit.after + 1, _in_between(engine, out, edit, guidance, (*loc, index)))
        seeds.insert(edit.after + 1, edit.seed)
    for op in ("append", "prepend"):
        for index, edit in enumerate(resolved):
            if isinstance(edit, ContinueEdit) and edit.op == op:
                before = len(out)
                out = _continue(engine, out, edit, guidance, (*loc, index))
                new = [edit.seed] * (len(out) - before)
                seeds = seeds + new if op == "append" else new + seeds
    return out, resolved, [(i, int(s)) for i, s in enumerate(seeds) if s is not None]


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
