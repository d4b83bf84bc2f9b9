"""Load a model bundle for the service: the contract's checks (t2m.bundle), then the onnxruntime sessions.

A bundle is all the service knows about a model, so everything the sampler relies on is checked here, once, at
start-up: the manifest's fields, each listed file's size and sha256 (t2m.bundle), and each graph's declared inputs
and outputs as onnxruntime sees them against the contract's signatures (t2m.bundle.bundle_graphs: the optional
encoder.onnx too where the manifest lists it), then what the
family's served loop needs beyond the contract (its `check_servable`).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import onnxruntime as ort

from t2m.bundle import (
    ENCODER_GRAPH,
    BundleError,
    DeclaredTensor,
    Manifest,
    bundle_graphs,
    check_files,
    check_graph_io,
    family_names,
    get_family,
    parse_manifest,
    read_manifest_dict,
    required_files,
)
from t2m.bundle.manifest import INT8_LABELS
from t2m.runtime.execution import Execution, ProviderError, check_available
from t2m.runtime.graphed_step import GraphedSession, graph_session

__all__ = ["Bundle", "BundleError", "Execution", "Manifest", "load_bundle", "open_session", "session_options"]

log = logging.getLogger(__name__)

# onnxruntime's type strings -> the contract's dtype names
_ORT_DTYPES = {"tensor(float)": "float32", "tensor(int64)": "int64", "tensor(int32)": "int32",
               "tensor(float16)": "float16", "tensor(bool)": "bool"}


def _check_served_family(raw: dict) -> None:
    """Refuse a family this service has no decoding loop for before its family-specific fields are read."""
    family = raw.get("family", "gpt")
    known = family_names()
    if family not in known:
        raise BundleError(f"manifest.json: field 'family' must be one of {list(known)} (the families this service "
                          f"runs), got {family!r}")


def session_options(intra_op_threads: int = 0, inter_op_threads: int = 1) -> ort.SessionOptions:
    """Options shared by the three sessions: full graph optimisation, sequential execution, the thread budget."""
    options = ort.SessionOptions()
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    options.intra_op_num_threads = intra_op_threads
    options.inter_op_num_threads = inter_op_threads
    options.log_severity_level = 3
    return options


def open_captured(file: Path, options: ort.SessionOptions, execution: Execution) -> ort.InferenceSession | None:
    """The graph's session with CUDA-graph capture (T2M_CUDA_GRAPHS), or None with a warning where onnxruntime
    refuses it: a graph exported before its shape arithmetic was kept off the CPU (Range or an attention scale fed
    by Shape: t2m/export/graphs/capture_check.py) makes its CUDA provider copy inside a run."""
    try:
        session = graph_session(file, execution.ort_providers, cuda_graph=True, options=options)
        execution.check_session(session, file.name)
        return session
    except ProviderError:
        raise
    except Exception as error:   # onnxruntime's Fail: "cannot use the graph capture feature ..."
        log.warning("T2M_CUDA_GRAPHS: %s cannot be captured as a CUDA graph (%s); going on without its capture "
                    "(graphs exported or imported by this version capture)", file, str(error).splitlines()[0][:200])
        return None


def open_replayed(file: Path, options: ort.SessionOptions, execution: Execution) -> GraphedSession:
    """A replayable graph (engine/graphed_step.py's GraphedSession), captured where onnxruntime allows, else
    plain calls through the same wrapper."""
    session = open_captured(file, options, execution)
    if session is None:
        return GraphedSession(open_session(file, options, execution), cuda_graph=False, max_shapes=0)
    return GraphedSession(session, cuda_graph=execution.on_gpu, max_shapes=execution.graph_shapes)


def open_session(file: Path | bytes, options: ort.SessionOptions,
                 execution: Execution | None = None) -> ort.InferenceSession:
    """A graph's session on the execution's providers (default: CPU only); a session that could not get the first
    provider it asked for is refused naming T2M_EXECUTION_PROVIDERS (engine/execution.py)."""
    execution = execution or Execution()
    name = str(file) if isinstance(file, Path) else "an in-memory graph"
    try:
        session = ort.InferenceSession(str(file) if isinstance(file, Path) else file, sess_options=options,
                                       providers=execution.ort_providers)
    except Exception as error:  # onnxruntime raises its own exception types for a broken graph
        raise BundleError(f"{name}: onnxruntime cannot load the graph ({str(error).splitlines()[0]})") from None
    execution.check_session(session, name)
    return session


def _check_session(session: ort.InferenceSession, file: str, manifest: Manifest) -> None:
    """The graph's declared inputs/outputs, as onnxruntime reads them, against the contract's signature."""
    def declared(args: list) -> list[DeclaredTensor]:
        return [DeclaredTensor(arg.name, _ORT_DTYPES.get(arg.type, arg.type), tuple(arg.shape)) for arg in args]

    check_graph_io(file, declared(session.get_inputs()), declared(session.get_outputs()),
                   bundle_graphs(manifest.raw)[file])


@dataclass
class Bundle:
    """A verified bundle: its manifest, its onnxruntime sessions and the tokenizer file; `sessions` holds every graph
    by file name (the family's own graphs are read from there by its served object)."""

    path: Path
    manifest: Manifest
    text_session: ort.InferenceSession
    decoder_session: ort.InferenceSession
    mean: np.ndarray
    std: np.ndarray
    sessions: dict[str, ort.InferenceSession] = field(default_factory=dict)
    execution: Execution = field(default_factory=Execution)
    # with T2M_CUDA_GRAPHS: the family's replayable graphs (their sessions are also in `sessions`) wrapped to be
    # replayed as CUDA graphs; the family's steps call these instead
    replays: dict[str, GraphedSession] = field(default_factory=dict)

    def step_session(self, file: str) -> ort.InferenceSession | GraphedSession | None:
        """What a family's steps call for `file`: its replayed copy where T2M_CUDA_GRAPHS made one, else its
        session (None: the bundle has no such graph)."""
        return self.replays.get(file) or self.sessions.get(file)

    @property
    def encoder_session(self) -> ort.InferenceSession | None:
        """encoder.onnx (features -> codes) where the bundle has one, else None: uploaded motions are refused."""
        return self.sessions.get(ENCODER_GRAPH)

    @property
    def cuda_graphs(self) -> list[str]:
        """The graphs replayed as CUDA graphs (what /health reports): none off a GPU."""
        if not self.execution.on_gpu:
            return []
        captured = get_family(self.manifest.family).captured_graphs(self.manifest.raw)
        return sorted([file for file, graph in self.replays.items() if graph.cuda_graph] +
                      [file for file in captured if file in self.sessions])

    @property
    def tokenizer_file(self) -> Path:
        return self.path / "tokenizer.json"


def _load_array(path: Path, manifest: Manifest) -> np.ndarray:
    try:
        array = np.load(path, allow_pickle=False)
    except ValueError as error:
        raise BundleError(f"{path}: not a numpy array file ({error})") from None
    if array.shape != (manifest.feature_dim,):
        raise BundleError(f"{path}: shape {array.shape}, expected ({manifest.feature_dim},)")
    return array


def _warn_int8_on_gpu(raw: dict, path: Path, execution: Execution) -> None:
    """int8 step graphs on a GPU provider: their activation quantisation has no CUDA kernel and goes to the CPU and
    back (the default model 0.3.0 on an H100: 2.9x fewer motions per second than its float32 copy at batch 256;
    measured with activations per tensor, not yet per row), so say which copy to serve instead; the text encoder runs
    once per sentence and does not matter."""
    if not execution.on_gpu:
        return
    int8 = sorted(graph for graph, label in (raw.get("quantization") or {}).items()
                  if label in INT8_LABELS and graph != "text_encoder")
    if int8:
        log.warning("%s: %s are int8, slow on %s (their quantised MatMuls run on the CPU); serve a float copy: "
                    "t2m quantize %s -o DIR --scheme float32 (or fp16)", path, ", ".join(int8),
                    ",".join(execution.providers), path)


def load_bundle(path: str | Path, *, check_hashes: bool = True, intra_op_threads: int = 0,
                inter_op_threads: int = 1, execution: Execution | None = None) -> Bundle:
    """Verify the bundle at `path` and open its graphs on `execution`'s providers (default: CPU); raises
    BundleError naming the first problem found (ProviderError, naming the setting, for a provider onnxruntime
    lacks: before any file is read)."""
    execution = execution or Execution()
    check_available(execution.providers)
    path = Path(path)
    raw = read_manifest_dict(path)
    _check_served_family(raw)
    manifest = parse_manifest(raw)
    check_files(path, manifest.files, check_hashes=check_hashes, required=required_files(raw))
    family = get_family(manifest.family)
    family.check_servable(manifest)
    options = session_options(intra_op_threads, inter_op_threads)
    replayable = set(family.replayable_graphs(raw)) if execution.cuda_graphs else set()
    captured = set(family.captured_graphs(raw))
    sessions, replays = {}, {}
    for file in bundle_graphs(raw):
        if file in captured:   # only for T2M_CUDA_GRAPHS, run by the family's own step class
            if execution.cuda_graphs and (session := open_captured(path / file, options, execution)) is not None:
                sessions[file] = session
                _check_session(session, file, manifest)
            continue
        if file in replayable:
            replays[file] = open_replayed(path / file, options, execution)
            sessions[file] = replays[file].session
        else:
            sessions[file] = open_session(path / file, options, execution)
        _check_session(sessions[file], file, manifest)
    log.info("loaded bundle %s %s (%s) from %s", manifest.name, manifest.version, manifest.family, path)
    _warn_int8_on_gpu(raw, path, execution)
    return Bundle(path=path, manifest=manifest, text_session=sessions["text_encoder.onnx"],
                  decoder_session=sessions["decoder.onnx"], mean=_load_array(path / "mean.npy", manifest),
                  std=_load_array(path / "std.npy", manifest), sessions=sessions,
                  execution=execution, replays=replays)
