"""A dataclass mixin for model configs: a plain dict in config.json, and a clear error for a field we do not know."""
from __future__ import annotations

from dataclasses import asdict, fields
from typing import Any, TypeVar

ConfigT = TypeVar("ConfigT", bound="ConfigDict")


class ConfigDict:
    """``to_dict`` / ``from_dict`` for a dataclass; ``from_dict`` refuses unknown fields, naming them."""

    label = "model"  # how error messages name the config ("joint VQ", "masked transformer", ...)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)  # type: ignore[call-overload]

    @classmethod
    def from_dict(cls: type[ConfigT], data: dict[str, Any]) -> ConfigT:
        known = {f.name for f in fields(cls)}  # type: ignore[arg-type]
        unknown = set(data) - known
        if unknown:
            raise ValueError(f"unknown {cls.label} config field(s): {', '.join(sorted(unknown))}")
        return cls(**data)

    def _require_positive(self, *names: str) -> None:
        for name in names:
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
