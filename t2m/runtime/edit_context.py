"""The maps an inpainting family's edit samples (t2m.decoding.inpaint): each edited segment between the kept codes
around it, so its family's loop fills it with both sides as context.

A sampled segment's map is: up to CONTEXT_ROWS kept rows before it (the tail of the kept segments just before it,
stopping at a segment that is itself sampled in the same edit, whose codes are not known yet), its own rows (all to
fill; for a body_part edit its old codes with only the part's columns over the span to fill) and up to CONTEXT_ROWS
kept rows after it; the map is cut to the model's max_tokens rows, taking context from the longer side first. The
map answers the segment's own rows; the context rows are only read.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np

from t2m.decoding.inpaint import Inpaint

__all__ = ["CONTEXT_ROWS", "context_sides", "inpaint_map"]

CONTEXT_ROWS = 10   # kept code rows on each side of an edit (2 s at 4 frames per row and 20 fps)


class _Planned(Protocol):
    codes: np.ndarray | None     # kept codes [steps, C, R], or None for a segment sampled by the edit


def _kept_run(segments: Sequence[_Planned], indices: range) -> list[np.ndarray]:
    """The kept segments' codes at `indices`, in that order, up to the first sampled one."""
    run = []
    for index in indices:
        codes = segments[index].codes
        if codes is None:
            break
        run.append(codes)
    return run


def context_sides(before: int, after: int, room: int, most: int = CONTEXT_ROWS) -> tuple[int, int]:
    """Context rows (before, after) from what each side has, each at most `most`, together at most `room` (the
    longer side gives first); also the diffusion family's in-between frames (service/diffusion_edits.py)."""
    left, right = min(before, most), min(after, most)
    while left + right > max(room, 0):
        if left >= right:
            left -= 1
        else:
            right -= 1
    return left, right


def inpaint_map(segments: Sequence[_Planned], position: int, own: np.ndarray, fill: np.ndarray,
                max_rows: int) -> Inpaint:
    """The map of the sampled segment at `position` of the edited motion's `segments`: `own` its codes (any values
    where `fill`), `fill` bool [steps, C] what to sample in it, between the kept context."""
    shape = own.shape[1:]
    empty = np.zeros((0, *shape), dtype=np.int64)
    before = _kept_run(segments, range(position - 1, -1, -1))[::-1]
    after = _kept_run(segments, range(position + 1, len(segments)))
    left_codes = np.concatenate([empty, *before])
    right_codes = np.concatenate([empty, *after])
    left, right = context_sides(len(left_codes), len(right_codes), max_rows - len(own))
    known = np.concatenate([left_codes[len(left_codes) - left:], own, right_codes[:right]]).astype(np.int64)
    kept = np.zeros((left, shape[0]), dtype=bool)
    full_fill = np.concatenate([kept, fill, np.zeros((right, shape[0]), dtype=bool)])
    return Inpaint(known, full_fill, (left, left + len(own)))
