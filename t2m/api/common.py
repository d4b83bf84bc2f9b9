"""What the API's models share: the strict base (unknown fields refused), the integer and text types, the output
formats, the error record in pydantic's shape."""
from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    StringConstraints,
)

from t2m.runtime.limits import (
    MAX_MODEL_NAME_CHARS,
    MAX_SEED,
    MAX_TEXT_CHARS,
)

OutputFormat = Literal["json", "bvh", "glb"]


def json_integer(value: Any) -> Any:
    """JSON Schema counts 3.0 as an integer; pass it on as 3 (1.5, true and "3" still fail the strict int check)."""
    if isinstance(value, float) and value.is_integer():
        return int(value)
    return value


Seed = Annotated[int, Field(ge=0, le=MAX_SEED), BeforeValidator(json_integer)]


TopK = Annotated[int, Field(ge=1), BeforeValidator(json_integer)]


class StrictModel(BaseModel):
    """Unknown fields refused, and no type coercion ("3" or true for a number), exactly as the JSON schema says."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)


ModelName = Annotated[str, StringConstraints(min_length=1, max_length=MAX_MODEL_NAME_CHARS)]


Text = Annotated[str, StringConstraints(strip_whitespace=True, min_length=1, max_length=MAX_TEXT_CHARS, pattern=r"\S")]


def field_error(loc: tuple[Any, ...], message: str, value: Any) -> dict[str, Any]:
    """An error in pydantic's shape so that FastAPI's 422 handler and our callers treat it the same way."""
    return {"type": "value_error", "loc": loc, "msg": message, "input": value}
