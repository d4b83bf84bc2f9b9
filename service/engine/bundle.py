"""Load a model bundle (docs/contracts.md) and refuse a broken one with an error that names the file or field.

A bundle is all the service knows about a model, so everything the sampler relies on is checked here, once, at
start-up: the manifest's fields, each listed file's size and sha256, and each graph's input/output names and ranks
(and the sizes that are fixed in the graph, e.g. the logits' width = codebook_size + 1).
"""
from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort

__all__ = ["BundleError", "Manifest", "Bundle", "load_manifest", "verify_files", "load_bundle", "session_options",
           "REQUIRED_FILES", "FORMAT_VERSION"]

log = logging.getLogger(__name__)

FORMAT_VERSION = 1
REQUIRED_FILES = ("manifest.json", "text_encoder.onnx", "tokenizer.json", "gpt_step.onnx", "decoder.onnx")


class BundleError(ValueError):
    """A bundle the service cannot use; the message names the bundle file or manifest field at fault."""


@dataclass(frozen=True)
class Manifest:
    """The manifest fields the service uses (the full JSON stays available as `raw`)."""

    name: str
    version: str
    fps: int
    skeleton: str
    num_joints: int
    feature_dim: int
    frames_per_token: int
    max_tokens: int
    codebook_size: int
    residual_layers: int
    end_id: int
    n_layer: int
    n_head: int
    head_dim: int
    block_size: int
    length_conditioning: bool
    unconditional_branch: bool
    default_guidance: float
    text_dim: int
    text_max_length: int
    files: dict[str, dict[str, Any]]
    raw: dict[str, Any]


def _field(data: dict[str, Any], key: str, kind: type, where: str) -> Any:
    """data[key], checked to be of `kind` (int means a JSON integer, not a bool); errors name the field."""
    if key not in data:
        raise BundleError(f"manifest.json: missing field '{where}{key}'")
    value = data[key]
    if isinstance(value, bool) and kind is not bool or not isinstance(value, kind):
        raise BundleError(f"manifest.json: field '{where}{key}' must be {kind.__name__}, got {value!r}")
    return value


def load_manifest(path: Path) -> Manifest:
    """Read and check manifest.json of the bundle directory `path`."""
    file = path / "manifest.json"
    if not path.is_dir():
        raise BundleError(f"bundle directory {path} does not exist")
    if not file.is_file():
        raise BundleError(f"{file}: missing file (a bundle needs manifest.json)")
    try:
        raw = json.loads(file.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise BundleError(f"{file}: not valid JSON ({error})") from None
    if not isinstance(raw, dict):
        raise BundleError(f"{file}: must hold a JSON object")
    version = raw.get("format_version")
    if version != FORMAT_VERSION:
        raise BundleError(f"manifest.json: field 'format_version' is {version!r}, this service reads {FORMAT_VERSION}")
    gpt = _field(raw, "gpt", dict, "")
    text = _field(raw, "text_encoder", dict, "")
    files = _field(raw, "files", dict, "")
    manifest = Manifest(
        name=str(_field(raw, "name", str, "")), version=str(_field(raw, "version", str, "")),
        fps=_field(raw, "fps", int, ""), skeleton=_field(raw, "skeleton", str, ""),
        num_joints=_field(raw, "num_joints", int, ""), feature_dim=_field(raw, "feature_dim", int, ""),
        frames_per_token=_field(raw, "frames_per_token", int, ""), max_tokens=_field(raw, "max_tokens", int, ""),
        codebook_size=_field(raw, "codebook_size", int, ""), residual_layers=_field(raw, "residual_layers", int, ""),
        end_id=_field(raw, "end_id", int, ""),
        n_layer=_field(gpt, "n_layer", int, "gpt."), n_head=_field(gpt, "n_head", int, "gpt."),
        head_dim=_field(gpt, "head_dim", int, "gpt."), block_size=_field(gpt, "block_size", int, "gpt."),
        length_conditioning=bool(gpt.get("length_conditioning", False)),
        unconditional_branch=bool(gpt.get("unconditional_branch", False)),
        default_guidance=float(gpt.get("default_guidance", 1.0)),
        text_dim=_field(text, "dim", int, "text_encoder."), text_max_length=_field(text, "max_length", int,
                                                                                    "text_encoder."),
        files=files, raw=raw)
    if manifest.end_id != manifest.codebook_size:
        raise BundleError(f"manifest.json: field 'end_id' is {manifest.end_id}, expected codebook_size "
                          f"{manifest.codebook_size} (End is the last logit)")
    if manifest.block_size < manifest.max_tokens + 1:
        raise BundleError(f"manifest.json: field 'gpt.block_size' {manifest.block_size} is smaller than "
                          f"max_tokens + 1 = {manifest.max_tokens + 1}")
    for key in ("fps", "frames_per_token", "max_tokens", "codebook_size", "residual_layers"):
        if getattr(manifest, key) < 1:
            raise BundleError(f"manifest.json: field {key!r} must be at least 1")
    if manifest.residual_layers != 1:
        raise BundleError(f"manifest.json: field 'residual_layers' is {manifest.residual_layers}; this service "
                          "samples one code per step and serves single-layer bundles only")
    return manifest


def _sha256(file: Path) -> str:
    digest = hashlib.sha256()
    with file.open("rb") as stream:
        for chunk in iter(lambda: stream.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def verify_files(path: Path, manifest: Manifest, check_hashes: bool = True) -> None:
    """Every required file present; every file listed in the manifest present with its size and sha256."""
    for name in REQUIRED_FILES:
        if not (path / name).is_file():
            raise BundleError(f"{path / name}: missing file")
    for name in REQUIRED_FILES[1:]:
        if name not in manifest.files:
            raise BundleError(f"manifest.json: field 'files' does not list {name!r}")
    for name, facts in manifest.files.items():
        file = path / name
        if not file.is_file():
            raise BundleError(f"{file}: missing file (listed in manifest.json 'files')")
        if not isinstance(facts, dict):
            raise BundleError(f"manifest.json: field 'files.{name}' must be an object with sha256 and bytes")
        size = file.stat().st_size
        if "bytes" in facts and size != facts["bytes"]:
            raise BundleError(f"{file}: size mismatch, {size} bytes on disk, manifest says {facts['bytes']}")
        if check_hashes and "sha256" in facts:
            actual = _sha256(file)
            if actual != str(facts["sha256"]).lower():
                raise BundleError(f"{file}: sha256 mismatch, {actual} on disk, manifest says {facts['sha256']}")


# name -> rank of each graph's inputs and outputs (docs/contracts.md). `length` is optional in gpt_step.
_TEXT_IO = ({"input_ids": 2, "attention_mask": 2}, {"text_features": 2})
_GPT_IO = ({"cond": 2, "token": 1, "position": 1, "past_kv": 6}, {"logits": 2, "present_kv": 6})
_DECODER_IO = ({"codes": 2}, {"features": 3})


def session_options(intra_op_threads: int = 0, inter_op_threads: int = 1) -> ort.SessionOptions:
    """Options shared by the three sessions: full graph optimisation, sequential execution, the thread budget."""
    options = ort.SessionOptions()
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    options.intra_op_num_threads = intra_op_threads
    options.inter_op_num_threads = inter_op_threads
    options.log_severity_level = 3
    return options


def _open_session(file: Path, options: ort.SessionOptions) -> ort.InferenceSession:
    try:
        return ort.InferenceSession(str(file), sess_options=options, providers=["CPUExecutionProvider"])
    except Exception as error:  # onnxruntime raises its own exception types for a broken graph
        raise BundleError(f"{file}: onnxruntime cannot load the graph ({str(error).splitlines()[0]})") from None


def _check_io(session: ort.InferenceSession, file: str, io: tuple[dict[str, int], dict[str, int]],
              optional: tuple[str, ...] = ()) -> dict[str, list]:
    """Names and ranks as the contract says; returns name -> shape (ints where fixed) of every input and output."""
    shapes: dict[str, list] = {}
    for kind, declared, expected in (("input", session.get_inputs(), io[0]), ("output", session.get_outputs(), io[1])):
        found = {arg.name: list(arg.shape) for arg in declared}
        shapes.update(found)
        for name, rank in expected.items():
            if name not in found:
                raise BundleError(f"{file}: graph has no {kind} {name!r} (has {sorted(found)})")
            if len(found[name]) != rank:
                raise BundleError(f"{file}: {kind} {name!r} has rank {len(found[name])}, expected {rank}")
        if kind == "input":
            unknown = set(found) - set(expected) - set(optional)
            if unknown:
                raise BundleError(f"{file}: unexpected graph inputs {sorted(unknown)}")
    return shapes


def _check_dim(shapes: dict[str, list], file: str, name: str, axis: int, expected: int, what: str) -> None:
    actual = shapes[name][axis]
    if isinstance(actual, int) and actual != expected:
        raise BundleError(f"{file}: {name} axis {axis} is {actual}, manifest {what} says {expected}")


@dataclass
class Bundle:
    """A verified bundle: its manifest, the three onnxruntime sessions and the tokenizer file."""

    path: Path
    manifest: Manifest
    text_session: ort.InferenceSession
    gpt_session: ort.InferenceSession
    decoder_session: ort.InferenceSession
    gpt_has_length_input: bool
    mean: np.ndarray | None = None
    std: np.ndarray | None = None

    @property
    def tokenizer_file(self) -> Path:
        return self.path / "tokenizer.json"


def load_bundle(path: str | Path, *, check_hashes: bool = True, intra_op_threads: int = 0,
                inter_op_threads: int = 1) -> Bundle:
    """Verify the bundle at `path` and open its graphs; raises BundleError naming the first problem found."""
    path = Path(path)
    manifest = load_manifest(path)
    verify_files(path, manifest, check_hashes=check_hashes)
    options = session_options(intra_op_threads, inter_op_threads)

    text = _open_session(path / "text_encoder.onnx", options)
    shapes = _check_io(text, "text_encoder.onnx", _TEXT_IO)
    _check_dim(shapes, "text_encoder.onnx", "text_features", 1, manifest.text_dim, "text_encoder.dim")

    gpt = _open_session(path / "gpt_step.onnx", options)
    shapes = _check_io(gpt, "gpt_step.onnx", _GPT_IO, optional=("length",))
    has_length = "length" in shapes
    if manifest.length_conditioning and not has_length:
        raise BundleError("gpt_step.onnx: graph has no input 'length' but manifest gpt.length_conditioning is true")
    if has_length and len(shapes["length"]) != 1:
        raise BundleError(f"gpt_step.onnx: input 'length' has rank {len(shapes['length'])}, expected 1")
    _check_dim(shapes, "gpt_step.onnx", "cond", 1, manifest.text_dim, "text_encoder.dim")
    _check_dim(shapes, "gpt_step.onnx", "logits", 1, manifest.codebook_size + 1, "codebook_size + 1")
    for axis, value, what in ((0, manifest.n_layer, "gpt.n_layer"), (1, 2, "(keys, values)"),
                              (3, manifest.n_head, "gpt.n_head"), (5, manifest.head_dim, "gpt.head_dim")):
        _check_dim(shapes, "gpt_step.onnx", "past_kv", axis, value, what)

    decoder = _open_session(path / "decoder.onnx", options)
    shapes = _check_io(decoder, "decoder.onnx", _DECODER_IO)
    _check_dim(shapes, "decoder.onnx", "features", 2, manifest.feature_dim, "feature_dim")

    mean = std = None
    for name in ("mean.npy", "std.npy"):
        if (path / name).is_file():
            try:
                array = np.load(path / name, allow_pickle=False)
            except ValueError as error:
                raise BundleError(f"{path / name}: not a numpy array file ({error})") from None
            if array.shape != (manifest.feature_dim,):
                raise BundleError(f"{path / name}: shape {array.shape}, expected ({manifest.feature_dim},)")
            mean, std = (array, std) if name == "mean.npy" else (mean, array)
    log.info("loaded bundle %s %s from %s", manifest.name, manifest.version, path)
    return Bundle(path=path, manifest=manifest, text_session=text, gpt_session=gpt, decoder_session=decoder,
                  gpt_has_length_input=has_length, mean=mean, std=std)
