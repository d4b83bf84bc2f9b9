"""Step graphs run from fixed device buffers, so that onnxruntime can capture a call as a CUDA graph and replay it:
gpt_step_fixed.onnx (`FixedCacheGptStep`) and any graph without a cache (`GraphedSession`, the masked family's).

Why: a release-size GPT step is ~500 small kernels, each launched from the host; on an H100 that launch work, not
arithmetic, is the step's 3.1-3.6 ms (docs/gpu.md). A CUDA graph replays all of a call's kernels with one launch,
but only if every replay has the same shapes and the same buffer addresses. So, for the GPT step:
- the graph's cache has a fixed capacity (t2m/families/gpt/fixed_cache.py) and each row its own position;
- a cohort gets one `FixedCache`: its inputs, its logits and two cache buffers live on the device for its whole
  life; a step reads one cache buffer and writes the other, the next step the other way round, so a cohort uses two
  captured graphs (one per direction), each with fixed addresses;
- rows that finish are not removed (that would change the batch): `keep_rows` only forgets them; they go on being
  computed, unread, until the cohort ends, and the finished cohort's buffers (and its graphs) serve the next cohort
  of the same batch size.
A graph without a cache needs only buffers per set of input shapes (`GraphedSession`).

The same classes run on the CPU provider (which ignores the graph ids), which is how tests/service/
test_graphed_step.py checks their outputs against the plain sessions'. Sampling stays on the host (the request's
numpy generator), so a seed gives the same motion on either device, as far as the float sums agree.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort

from t2m.runtime.bound_step import session_device

__all__ = ["FixedCache", "FixedCacheGptStep", "GraphedSession", "graph_session", "run_options"]


def graph_session(path: str | Path, providers: list[str], cuda_graph: bool,
                  options: ort.SessionOptions | None = None) -> ort.InferenceSession:
    """A session whose CUDA provider, with `cuda_graph`, captures and replays runs (FixedCacheGptStep,
    GraphedSession); the other providers as they are."""
    named: list[Any] = [(name, {"enable_cuda_graph": "1"}) if cuda_graph and name == "CUDAExecutionProvider" else name
                        for name in providers]
    return ort.InferenceSession(str(path), sess_options=options, providers=named)


_GRAPH_IDS = itertools.count(1)   # run_options's ids (per session in onnxruntime; one count never reuses one)


def run_options(cuda_graph: bool, graph_id: int) -> ort.RunOptions | None:
    """A run's options: with CUDA graphs, which graph it captures or replays (`graph_id` >= 1; -1: a plain run,
    nothing captured; onnxruntime reserves 0). The CPU provider ignores the id."""
    if not cuda_graph:
        return None
    options = ort.RunOptions()
    options.add_run_config_entry("gpu_graph_id", str(graph_id))
    return options


@dataclass
class FixedCache:
    """One cohort's device buffers: the step's inputs, its logits and the two cache buffers, plus which physical
    rows the loop still reads (`rows`) and which buffer the next step reads (`parity`)."""

    batch: int
    host: dict[str, np.ndarray]
    device: dict[str, ort.OrtValue]
    bindings: tuple[Any, Any]
    graph_ids: tuple[int, int]
    rows: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    parity: int = 0


class FixedCacheGptStep:
    """The GPT loop's step (t2m.families.gpt.loop.GptStep) over gpt_step_fixed.onnx; see the module docstring."""

    def __init__(self, session: ort.InferenceSession, n_layer: int, n_head: int, head_dim: int, capacity: int,
                 has_length_input: bool, cuda_graph: bool = False) -> None:
        self.session, self.has_length_input, self.cuda_graph = session, has_length_input, cuda_graph
        self.cache_shape = (n_layer, 2, -1, n_head, capacity, head_dim)
        self.device = session_device(session)
        inputs = {value.name: value for value in session.get_inputs()}
        self.text_dim = int(inputs["cond"].shape[1])
        self.vocabulary = int(session.get_outputs()[0].shape[1])
        self._free: dict[int, list[FixedCache]] = {}

    def empty_cache(self, batch: int) -> FixedCache:
        """A cohort's buffers: a finished cohort's of the same batch size when there is one, else new ones."""
        pool = self._free.setdefault(batch, [])
        cache = pool.pop() if pool else self._new_cache(batch)
        cache.rows, cache.parity = np.arange(batch), 0
        return cache

    def _new_cache(self, batch: int) -> FixedCache:
        shape = list(self.cache_shape)
        shape[2] = batch
        host: dict[str, np.ndarray] = {"cond": np.zeros((batch, self.text_dim), np.float32),
                                       "token": np.zeros(batch, np.int64), "position": np.zeros(batch, np.int64)}
        if self.has_length_input:
            host["length"] = np.zeros(batch, np.int64)
        device = {name: ort.OrtValue.ortvalue_from_numpy(value, self.device, 0) for name, value in host.items()}
        caches = [ort.OrtValue.ortvalue_from_numpy(np.zeros(shape, np.float32), self.device, 0) for _ in range(2)]
        device["logits"] = ort.OrtValue.ortvalue_from_numpy(np.zeros((batch, self.vocabulary), np.float32),
                                                             self.device, 0)
        bindings = []
        for past, present in ((caches[0], caches[1]), (caches[1], caches[0])):
            binding = self.session.io_binding()
            for name in host:
                binding.bind_ortvalue_input(name, device[name])
            binding.bind_ortvalue_input("past_kv", past)
            binding.bind_ortvalue_output("logits", device["logits"])
            binding.bind_ortvalue_output("present_kv", present)
            bindings.append(binding)
        return FixedCache(batch, host, device, (bindings[0], bindings[1]),
                          (next(_GRAPH_IDS), next(_GRAPH_IDS)))

    def __call__(self, cond: np.ndarray, token: np.ndarray, position: int, length: np.ndarray,
                 past: FixedCache) -> tuple[np.ndarray, FixedCache]:
        """(cond [n, Dt], previous token [n], position, length [n], the cohort's cache) for its n live rows ->
        (logits [n, V+1], the same cache, one position further)."""
        rows, host = past.rows, past.host
        changed = {"token", "position"}          # cond and length stay a cohort's while its rows do
        for name, value in (("cond", cond), ("length", length)):
            if name in host and not np.array_equal(host[name][rows], value):
                host[name][rows] = value
                changed.add(name)
        host["token"][rows] = token
        host["position"][:] = position
        for name in changed:                     # each copy to the device is a synchronous call
            past.device[name].update_inplace(host[name])
        self.session.run_with_iobinding(past.bindings[past.parity],
                                        run_options(self.cuda_graph, past.graph_ids[past.parity]))
        past.parity ^= 1
        return past.device["logits"].numpy()[rows], past

    def keep_rows(self, past: FixedCache, keep: np.ndarray) -> FixedCache:
        """Forget the rows where `keep` is false (they go on being computed, unread); a cohort with none left gives
        its buffers back for the next cohort of its batch size."""
        was_live = len(past.rows) > 0
        past.rows = past.rows[keep]
        if was_live and not len(past.rows):
            self._free[past.batch].append(past)
        return past


class GraphedSession:
    """`session.run` for graphs without a cache (the masked family's), replayed as a CUDA graph per set of input
    shapes: the first call of a shape runs plainly to learn its output shapes, then that shape gets device buffers
    for its inputs and outputs, bound once, and a graph id of its own. Each call copies its inputs into the buffers
    and its outputs back. A drop-in for `InferenceSession.run(names, feeds)` in the steps of engine/onnx_step.py.

    Every shape keeps its buffers and its captured graph for the session's life (onnxruntime has no call that
    frees one graph id's capture), so at most `max_shapes` shapes are captured, the first ones seen; later shapes run
    plainly (graph id -1). That suits loops whose shapes repeat (a batch of 10 s motions: the same shapes at every
    pass), and bounds the device memory of a server's ever-new batch sizes and lengths. Other attributes
    (get_inputs, get_providers) are the session's. One caller at a time (the engine's worker)."""

    def __init__(self, session: ort.InferenceSession, cuda_graph: bool, max_shapes: int = 16) -> None:
        self.session, self.cuda_graph, self.max_shapes = session, cuda_graph, max_shapes
        self.device = session_device(session)
        self.output_names = [value.name for value in session.get_outputs()]
        self._calls: dict[tuple, tuple[dict[str, ort.OrtValue], dict[str, ort.OrtValue], Any, int]] = {}

    def __getattr__(self, name: str) -> Any:
        return getattr(self.session, name)

    @property
    def captured_shapes(self) -> int:
        return len(self._calls)

    def run(self, output_names: list[str] | None, feeds: dict[str, np.ndarray]) -> list[np.ndarray]:
        feeds = {name: np.ascontiguousarray(value) for name, value in feeds.items()}
        key = tuple((name, value.shape, value.dtype.str) for name, value in sorted(feeds.items()))
        if key not in self._calls and len(self._calls) >= self.max_shapes:
            return self.session.run(output_names, feeds, run_options(self.cuda_graph, -1))
        if key not in self._calls:
            first = self.session.run(None, feeds, run_options(self.cuda_graph, -1))   # only the shapes
            inputs = {name: ort.OrtValue.ortvalue_from_numpy(value, self.device, 0) for name, value in feeds.items()}
            outputs = {name: ort.OrtValue.ortvalue_from_numpy(np.zeros_like(value), self.device, 0)
                       for name, value in zip(self.output_names, first)}
            binding = self.session.io_binding()
            for name, value in inputs.items():
                binding.bind_ortvalue_input(name, value)
            for name, value in outputs.items():
                binding.bind_ortvalue_output(name, value)
            self._calls[key] = (inputs, outputs, binding, next(_GRAPH_IDS))
        inputs, outputs, binding, graph_id = self._calls[key]
        for name, value in feeds.items():
            inputs[name].update_inplace(value)
        self.session.run_with_iobinding(binding, run_options(self.cuda_graph, graph_id))
        # copies: on the CPU provider numpy() is a view of the buffer that the next call of this shape overwrites
        return [np.array(outputs[name].numpy()) for name in (output_names or self.output_names)]
