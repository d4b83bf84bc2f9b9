"""Where the model sessions run: the execution providers (T2M_EXECUTION_PROVIDERS) and whether the step graphs keep
their key/value caches on the device through onnxruntime's I/O binding (T2M_IO_BINDING).

Why one small object: the bundle loader opens every session with these providers, and the families' served objects
pick their step classes from it (engine/bound_step.py when binding), so the choice is made once, at start-up, and a
provider the installed onnxruntime lacks is refused there in one line naming the setting, never mid-request.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import onnxruntime as ort

__all__ = ["PROVIDERS", "SETTING", "Execution", "ProviderError", "check_available", "ort_providers"]

SETTING = "T2M_EXECUTION_PROVIDERS"
# the setting's names -> onnxruntime's; CPU is always the last resort (ops a GPU provider lacks fall back to it)
PROVIDERS = {"cpu": "CPUExecutionProvider", "cuda": "CUDAExecutionProvider"}
# what to install for each provider's onnxruntime build
_PACKAGES = {"cuda": "onnxruntime-gpu (pip install 't2m-service[gpu]', which replaces the CPU-only onnxruntime)"}

IoBinding = Literal["auto", "on", "off"]


class ProviderError(ValueError):
    """A requested execution provider that this onnxruntime cannot give; the message names the setting."""


def ort_providers(names: Sequence[str]) -> list[str]:
    """onnxruntime's provider names for the setting's list, in order, CPU appended when absent ('cuda' = CUDA, then
    CPU); an unknown name is a ProviderError naming the setting."""
    result = []
    for name in names:
        if name not in PROVIDERS:
            raise ProviderError(f"{SETTING}: unknown provider {name!r}; use a comma-separated list of "
                                f"{', '.join(PROVIDERS)}")
        if PROVIDERS[name] not in result:
            result.append(PROVIDERS[name])
    if PROVIDERS["cpu"] not in result:
        result.append(PROVIDERS["cpu"])
    return result


def check_available(names: Sequence[str], available: Sequence[str] | None = None) -> None:
    """Raise a one-line ProviderError naming the setting when the installed onnxruntime lacks a requested provider
    (`available`: onnxruntime's list, by default the installed build's)."""
    have = list(ort.get_available_providers() if available is None else available)
    for name in names:
        provider = ort_providers([name])[0]
        if provider not in have:
            hint = f"; install {_PACKAGES[name]}" if name in _PACKAGES else ""
            raise ProviderError(f"{SETTING}={','.join(names)}: onnxruntime {ort.__version__} has no {provider} "
                                f"(available: {', '.join(have)}){hint}")


@dataclass(frozen=True)
class Execution:
    """The providers every session of a bundle gets, and whether the step graphs bind their caches to the device."""

    providers: tuple[str, ...] = ("cpu",)
    io_binding: IoBinding = "auto"
    # step graphs captured as CUDA graphs (the family's replayable graphs, up to `graph_shapes` input shapes each,
    # and its captured step graphs: engine/graphed_step.py); on the CPU provider the same buffers, no capture
    cuda_graphs: bool = False
    graph_shapes: int = 16

    def __post_init__(self) -> None:
        ort_providers(self.providers)   # unknown names fail here, naming the setting
        if self.io_binding not in ("auto", "on", "off"):
            raise ProviderError(f"T2M_IO_BINDING: must be auto, on or off, got {self.io_binding!r}")
        if self.graph_shapes < 1:
            raise ProviderError(f"T2M_CUDA_GRAPH_SHAPES: must be at least 1, got {self.graph_shapes}")

    @property
    def ort_providers(self) -> list[str]:
        return ort_providers(self.providers)

    @property
    def on_gpu(self) -> bool:
        """Whether a provider other than the CPU's is asked for."""
        return any(name != "cpu" for name in self.providers)

    @property
    def binds(self) -> bool:
        """Bound step caches: on with a GPU provider (auto), or forced on/off (tests force it on CPU)."""
        if self.io_binding == "auto":
            return self.on_gpu
        return self.io_binding == "on"

    def check_session(self, session: ort.InferenceSession, file: str) -> None:
        """A session that quietly fell back to CPU (onnxruntime-gpu without a usable GPU or CUDA libraries) is
        refused: serving on CPU while the operator asked for CUDA would only be found by its speed."""
        wanted = self.ort_providers[0]
        if wanted not in session.get_providers():
            raise ProviderError(f"{SETTING}={','.join(self.providers)}: {file}: onnxruntime could not start "
                                f"{wanted} (the session has {', '.join(session.get_providers())}); check the GPU, "
                                "its driver and the CUDA libraries onnxruntime-gpu needs")
