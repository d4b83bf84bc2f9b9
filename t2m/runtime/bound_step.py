"""The step graphs with their key/value caches kept on the session's device (onnxruntime's I/O binding).

Why: on a GPU, handing the cache to numpy and back at every step copies the whole past twice per token (for a
release-size GPT at batch 64 that is hundreds of MB a step), which costs more than the step itself. Here the cache
a step returns is an `OrtValue` on the device (an opaque handle to the decoding loops), fed to the next step as it
is; only what the sampler reads (logits, a stop logit, the HiFiGPT context) comes back to the host. When segments
finish, the loop asks the step to `keep_rows` (t2m.decoding.lockstep.keep_rows), which gathers the rows still
stepping on the device with a one-node graph (keep_rows.onnx, written by scripts/keep_rows_graph.py).

The same code runs with the CPU provider (OrtValues on 'cpu'), which is how the tests check it against the plain
numpy steps: the same kernels on the same values, so the same logits and codes.
"""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort

from t2m.runtime.onnx_step import OnnxGptStep, OnnxResidualGptStep, OnnxTemporalStep

__all__ = ["KEEP_ROWS_GRAPH", "BoundGptStep", "BoundResidualGptStep", "BoundTemporalStep", "CacheBinding",
           "host_cache", "session_device"]

KEEP_ROWS_GRAPH = Path(__file__).resolve().parent / "keep_rows.onnx"
# onnxruntime's provider -> the device name its OrtValues and bindings use
_DEVICES = {"CUDAExecutionProvider": "cuda", "CPUExecutionProvider": "cpu"}


def session_device(session: ort.InferenceSession) -> str:
    """Where the session's first provider keeps tensors ('cuda' or 'cpu')."""
    return _DEVICES.get(session.get_providers()[0], "cpu")


class CacheBinding:
    """One step graph run through an I/O binding: host inputs in, the cache in and out on the device, the outputs
    the sampler needs back on the host; and the rows of a cache kept on the device."""

    def __init__(self, session: ort.InferenceSession, host_outputs: Sequence[str]) -> None:
        self.session, self.host_outputs = session, tuple(host_outputs)
        self.device = session_device(session)
        options = ort.SessionOptions()
        options.intra_op_num_threads, options.inter_op_num_threads = 1, 1
        options.log_severity_level = 3
        self._gather = ort.InferenceSession(str(KEEP_ROWS_GRAPH), sess_options=options,
                                            providers=session.get_providers())

    def run(self, feeds: dict[str, np.ndarray], past: Any) -> tuple[list[np.ndarray], ort.OrtValue]:
        """The host outputs (in `host_outputs` order) and the new cache (an OrtValue on the device)."""
        binding = self.session.io_binding()
        for name, value in feeds.items():
            binding.bind_cpu_input(name, np.ascontiguousarray(value))
        _bind_cache(binding, "past_kv", past)
        for name in self.host_outputs:
            binding.bind_output(name, "cpu")
        binding.bind_output("present_kv", self.device, 0)
        self.session.run_with_iobinding(binding)
        *host, present = binding.get_outputs()
        return [value.numpy() for value in host], present

    def keep_rows(self, past: Any, keep: np.ndarray) -> Any:
        """The cache's rows where `keep` is true (batch axis 2), staying where the cache is."""
        if isinstance(past, np.ndarray):
            return past[:, :, keep]
        rows = np.flatnonzero(keep).astype(np.int64)
        if not len(rows):   # nothing steps any more: no device buffer needed
            shape = list(past.shape())
            shape[2] = 0
            return np.zeros(shape, dtype=np.float32)
        binding = self._gather.io_binding()
        _bind_cache(binding, "past", past)
        binding.bind_cpu_input("rows", rows)
        binding.bind_output("kept", self.device, 0)
        self._gather.run_with_iobinding(binding)
        return binding.get_outputs()[0]


def _bind_cache(binding: Any, name: str, past: Any) -> None:
    """A cache is an OrtValue on the device, or a host array (the empty one a cohort starts with)."""
    if isinstance(past, np.ndarray):
        binding.bind_cpu_input(name, np.ascontiguousarray(past))
    else:
        binding.bind_ortvalue_input(name, past)


def host_cache(past: Any) -> np.ndarray:
    """A cache as a numpy array wherever it lives (tests and debugging)."""
    return past if isinstance(past, np.ndarray) else past.numpy()


class BoundGptStep(OnnxGptStep):
    """gpt_step.onnx with its cache on the device: only the logits come back to the host."""

    def __init__(self, session: ort.InferenceSession, n_layer: int, n_head: int, head_dim: int,
                 has_length_input: bool) -> None:
        super().__init__(session, n_layer, n_head, head_dim, has_length_input)
        self.binding = CacheBinding(session, ["logits"])

    def __call__(self, cond: np.ndarray, token: np.ndarray, position: int, length: np.ndarray,
                 past: Any) -> tuple[np.ndarray, Any]:
        (logits,), present = self.binding.run(self.feeds(cond, token, position, length), past)
        return logits, present

    def keep_rows(self, past: Any, keep: np.ndarray) -> Any:
        return self.binding.keep_rows(past, keep)


class BoundTemporalStep(OnnxTemporalStep):
    """temporal_step.onnx with its cache on the device: the context and the stop logit come back to the host."""

    def __init__(self, session: ort.InferenceSession, depth: int, n_layer: int, n_head: int, head_dim: int,
                 has_length_input: bool) -> None:
        super().__init__(session, depth, n_layer, n_head, head_dim, has_length_input)
        self.binding = CacheBinding(session, ["context", "stop_logit"])

    def __call__(self, cond: np.ndarray, codes: np.ndarray, position: int, length: np.ndarray,
                 past: Any) -> tuple[np.ndarray, np.ndarray, Any]:
        (context, stop), present = self.binding.run(self.feeds(cond, codes, position, length), past)
        return context, stop, present

    def keep_rows(self, past: Any, keep: np.ndarray) -> Any:
        return self.binding.keep_rows(past, keep)


class BoundResidualGptStep(OnnxResidualGptStep):
    """residual_step.onnx with its (per time step) cache on the device: only the logits come back to the host."""

    def __init__(self, session: ort.InferenceSession, n_layer: int, n_head: int, head_dim: int) -> None:
        super().__init__(session, n_layer, n_head, head_dim)
        self.binding = CacheBinding(session, ["logits"])

    def __call__(self, context: np.ndarray, code: np.ndarray, depth: int, past: Any) -> tuple[np.ndarray, Any]:
        (logits,), present = self.binding.run(self.feeds(context, code, depth), past)
        return logits, present

    def keep_rows(self, past: Any, keep: np.ndarray) -> Any:
        return self.binding.keep_rows(past, keep)
