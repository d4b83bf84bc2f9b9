"""The models one service serves, each found by its manifest name, the first bundle being the default.

Every model has its own engine and its own batcher (queue and worker threads), so requests for different models
never share a batch: a busy model neither delays another model's requests nor changes their motions.
"""
from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

from t2m.runtime.scheduling import QueuedWorkers
from t2m.runtime.types import Engine, ModelLimits

__all__ = ["DuplicateModelError", "LoadedEngine", "ModelLoadError", "ModelRegistry", "ServedModel", "load_engines"]


class ModelLoadError(RuntimeError):
    """A bundle could not be loaded; the message names its directory."""


class DuplicateModelError(ModelLoadError):
    """Two bundles carry the same manifest name, so a request could not say which one it means."""


@dataclass(frozen=True)
class LoadedEngine:
    """An engine fresh from its bundle directory, before it gets a batcher."""

    directory: Path
    engine: Engine
    load_seconds: float


@dataclass(frozen=True)
class ServedModel:
    """One model of the service: its engine, the batcher that feeds it, and where it came from."""

    directory: Path
    engine: Engine
    batcher: QueuedWorkers
    load_seconds: float

    @property
    def limits(self) -> ModelLimits:
        return self.engine.limits

    @property
    def name(self) -> str:
        return self.engine.limits.name


class ModelRegistry:
    """The served models in the order they were configured; lookup by manifest name, None meaning the default."""

    def __init__(self, models: Sequence[ServedModel]) -> None:
        if not models:
            raise ValueError("a service needs at least one model")
        self._models = {model.name: model for model in models}
        if len(self._models) != len(models):
            raise DuplicateModelError("two served models share a manifest name")
        self.default = models[0]

    def __iter__(self) -> Iterator[ServedModel]:
        return iter(self._models.values())

    def __len__(self) -> int:
        return len(self._models)

    @property
    def names(self) -> list[str]:
        return list(self._models)

    def get(self, name: str | None) -> ServedModel | None:
        """The model called `name` (None = the default); None when no model has that name."""
        return self.default if name is None else self._models.get(name)

    def close(self) -> None:
        for model in self:
            model.batcher.close()


def load_engines(directories: Sequence[Path], load: Callable[[Path], Engine]) -> list[LoadedEngine]:
    """Load each bundle in order; a failure names its directory, and a repeated manifest name stops the load."""
    loaded: list[LoadedEngine] = []
    for directory in directories:
        started = time.perf_counter()
        try:
            engine = load(directory)
        except Exception as error:
            message = str(error) if str(directory) in str(error) else f"model bundle {directory}: {error}"
            raise ModelLoadError(message) from error
        name = engine.limits.name
        earlier = next((item.directory for item in loaded if item.engine.limits.name == name), None)
        if earlier is not None:
            raise DuplicateModelError(
                f"model bundles {earlier} and {directory} are both named {name!r}; every served model needs its own "
                "manifest name (the request's `model` field picks a model by it)")
        loaded.append(LoadedEngine(directory, engine, time.perf_counter() - started))
    return loaded

