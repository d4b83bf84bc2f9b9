"""One entry for an edit made on an engine directly, no server (`t2m edit`, the benchmarks), as POST /edit chooses:
a token model's handle through t2m.runtime.editing (its parts sampled, the codes decoded once), a recipe (the
diffusion family's) by the model's own served object (replayed and inpainted on its frames)."""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from t2m.runtime.editing import AnyEdit, EditResult, edit_in_process
from t2m.runtime.handles import MotionHandle
from t2m.runtime.types import RecipeEditingEngine

__all__ = ["edit_with_engine"]


def edit_with_engine(engine: Any, handle: str | MotionHandle, edits: Sequence[AnyEdit]) -> EditResult:
    """The edit of `handle` (a handle or recipe string, or an uploaded motion's read handle) by `engine`'s model."""
    if engine.limits.recipe and isinstance(handle, str) and isinstance(engine, RecipeEditingEngine):
        result: EditResult = engine.edit_recipe(handle, edits)
        return result
    return edit_in_process(engine, handle, edits)
