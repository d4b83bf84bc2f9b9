"""Re-check a bundle directory against docs/contracts.md: manifest fields, file hashes and sizes, graph signatures.

The service refuses a bad bundle at load time; this module lets the exporter (and a user, via
``python -m export.verify DIR``) find the same problems before a bundle ships. It reads graph
signatures with ``onnx`` (no weights are loaded, so it is fast even for the 1 GB T2M-GPT import).
Every problem raises :class:`BundleVerificationError` naming the file or the manifest field.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

FORMAT_VERSION = 1
MANIFEST_NAME = "manifest.json"
REQUIRED_FILES = (
    "text_encoder.onnx",
    "tokenizer.json",
    "gpt_step.onnx",
    "decoder.onnx",
    "mean.npy",
    "std.npy",
    "MODEL_CARD.md",
)
INT64 = "int64"
FLOAT32 = "float32"


class BundleVerificationError(ValueError):
    """A bundle that does not satisfy the contract; the message names the file or manifest field."""


@dataclass(frozen=True)
class TensorSpec:
    """Name, element type and shape of one graph input/output; an int dim is checked, None is free (dynamic)."""

    name: str
    dtype: str
    shape: tuple[int | None, ...]

    @property
    def rank(self) -> int:
        return len(self.shape)


@dataclass(frozen=True)
class GraphSpec:
    inputs: tuple[TensorSpec, ...]
    outputs: tuple[TensorSpec, ...]


# ---------------------------------------------------------------------------------------------- manifest fields

def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return (isinstance(value, (int, float))) and not isinstance(value, bool)


def _is_str(value: Any) -> bool:
    return isinstance(value, str) and value != ""


def _is_bool(value: Any) -> bool:
    return isinstance(value, bool)


def _is_optional_str(value: Any) -> bool:
    return value is None or _is_str(value)


# field path -> (check, what it must be)
MANIFEST_FIELDS: dict[str, tuple[Any, str]] = {
    "format_version": (lambda v: v == FORMAT_VERSION, f"the integer {FORMAT_VERSION}"),
    "name": (_is_str, "a non-empty string"),
    "version": (_is_str, "a non-empty string"),
    "fps": (lambda v: _is_int(v) and v > 0, "a positive integer"),
    "skeleton": (_is_str, "a skeleton name such as 'smpl22'"),
    "num_joints": (lambda v: _is_int(v) and v > 0, "a positive integer"),
    "feature_dim": (lambda v: _is_int(v) and v > 0, "a positive integer"),
    "frames_per_token": (lambda v: _is_int(v) and v > 0, "a positive integer"),
    "max_tokens": (lambda v: _is_int(v) and v > 0, "a positive integer"),
    "codebook_size": (lambda v: _is_int(v) and v > 0, "a positive integer"),
    "residual_layers": (lambda v: _is_int(v) and v > 0, "a positive integer"),
    "end_id": (_is_int, "an integer"),
    "gpt.n_layer": (lambda v: _is_int(v) and v > 0, "a positive integer"),
    "gpt.n_head": (lambda v: _is_int(v) and v > 0, "a positive integer"),
    "gpt.head_dim": (lambda v: _is_int(v) and v > 0, "a positive integer"),
    "gpt.block_size": (lambda v: _is_int(v) and v > 1, "an integer > 1"),
    "gpt.length_conditioning": (_is_bool, "true or false"),
    "gpt.unconditional_branch": (_is_bool, "true or false"),
    "gpt.default_guidance": (lambda v: _is_number(v) and v >= 0, "a number >= 0"),
    "text_encoder.kind": (_is_str, "a string such as 'minilm' or 'clip'"),
    "text_encoder.dim": (lambda v: _is_int(v) and v > 0, "a positive integer"),
    "text_encoder.max_length": (lambda v: _is_int(v) and v > 1, "an integer > 1"),
    "text_encoder.pooling": (_is_str, "a string such as 'mean' or 'eot'"),
    "text_encoder.normalize": (_is_bool, "true or false"),
    "text_encoder.null_condition": (lambda v: v == "zeros", "'zeros'"),
    "training_data.name": (_is_str, "a non-empty string"),
    "training_data.license": (_is_str, "a non-empty string"),
    "training_data.attribution": (lambda v: isinstance(v, str), "a string"),
    "license": (_is_str, "a non-empty string"),
    "quantization.text_encoder": (_is_optional_str, "null or a string such as 'int8-dynamic'"),
    "quantization.gpt_step": (_is_optional_str, "null or a string such as 'int8-dynamic'"),
    "files": (lambda v: isinstance(v, dict) and bool(v), "an object {file name: {sha256, bytes}}"),
}


def _lookup(manifest: Mapping[str, Any], dotted: str) -> Any:
    value: Any = manifest
    for part in dotted.split("."):
        if not isinstance(value, Mapping) or part not in value:
            raise BundleVerificationError(f"{MANIFEST_NAME}: missing field '{dotted}'")
        value = value[part]
    return value


def check_manifest_fields(manifest: Mapping[str, Any]) -> None:
    """Every contract field present with the right type, and the fields consistent with each other."""
    if not isinstance(manifest, Mapping):
        raise BundleVerificationError(f"{MANIFEST_NAME}: must be a JSON object")
    for dotted, (check, expected) in MANIFEST_FIELDS.items():
        value = _lookup(manifest, dotted)
        if not check(value):
            raise BundleVerificationError(f"{MANIFEST_NAME}: field '{dotted}' must be {expected}, got {value!r}")
    if manifest["end_id"] != manifest["codebook_size"]:
        raise BundleVerificationError(
            f"{MANIFEST_NAME}: field 'end_id' must equal codebook_size ({manifest['codebook_size']}),"
            f" got {manifest['end_id']}"
        )
    block_size = manifest["gpt"]["block_size"]
    if manifest["max_tokens"] > block_size - 1:
        raise BundleVerificationError(
            f"{MANIFEST_NAME}: field 'max_tokens' ({manifest['max_tokens']}) exceeds gpt.block_size - 1 ({block_size - 1})"
        )


# ------------------------------------------------------------------------------------------------- graph specs

def expected_graphs(manifest: Mapping[str, Any]) -> dict[str, GraphSpec]:
    """The input/output names, types and (static where known) dims each graph must have for this manifest."""
    gpt = manifest["gpt"]
    dim = manifest["text_encoder"]["dim"]
    kv = (gpt["n_layer"], 2, None, gpt["n_head"], None, gpt["head_dim"])
    step_inputs = [
        TensorSpec("cond", FLOAT32, (None, dim)),
        TensorSpec("token", INT64, (None,)),
        TensorSpec("position", INT64, (1,)),
    ]
    if gpt["length_conditioning"]:
        step_inputs.append(TensorSpec("length", INT64, (None,)))
    step_inputs.append(TensorSpec("past_kv", FLOAT32, kv))
    residual = manifest["residual_layers"]
    codes_shape: tuple[int | None, ...] = (None, None) if residual == 1 else (None, None, residual)
    return {
        "text_encoder.onnx": GraphSpec(
            inputs=(TensorSpec("input_ids", INT64, (None, None)), TensorSpec("attention_mask", INT64, (None, None))),
            outputs=(TensorSpec("text_features", FLOAT32, (None, dim)),),
        ),
        "gpt_step.onnx": GraphSpec(
            inputs=tuple(step_inputs),
            outputs=(
                TensorSpec("logits", FLOAT32, (None, manifest["codebook_size"] + 1)),
                TensorSpec("present_kv", FLOAT32, kv),
            ),
        ),
        "decoder.onnx": GraphSpec(
            inputs=(TensorSpec("codes", INT64, codes_shape),),
            outputs=(TensorSpec("features", FLOAT32, (None, None, manifest["feature_dim"])),),
        ),
    }


def _value_info_spec(value_info: Any) -> tuple[str, tuple[int | str | None, ...]]:
    import onnx

    tensor_type = value_info.type.tensor_type
    dtype = onnx.helper.tensor_dtype_to_np_dtype(tensor_type.elem_type).name if tensor_type.elem_type else "?"
    dims: list[int | str | None] = []
    for d in tensor_type.shape.dim:
        if d.HasField("dim_value"):
            dims.append(int(d.dim_value))
        else:
            dims.append(d.dim_param or None)
    return dtype, tuple(dims)


def _check_tensors(file: str, role: str, actual: list[Any], expected: tuple[TensorSpec, ...]) -> None:
    actual_names = [v.name for v in actual]
    expected_names = [s.name for s in expected]
    if sorted(actual_names) != sorted(expected_names):
        raise BundleVerificationError(
            f"{file}: graph {role}s are {actual_names}, the manifest requires {expected_names}"
        )
    by_name = {v.name: v for v in actual}
    for spec in expected:
        dtype, dims = _value_info_spec(by_name[spec.name])
        if dtype != spec.dtype:
            raise BundleVerificationError(f"{file}: {role} '{spec.name}' has type {dtype}, expected {spec.dtype}")
        if len(dims) != spec.rank:
            raise BundleVerificationError(
                f"{file}: {role} '{spec.name}' has rank {len(dims)} {list(dims)}, expected rank {spec.rank}"
            )
        for axis, (got, want) in enumerate(zip(dims, spec.shape)):
            if want is not None and isinstance(got, int) and got != want:
                raise BundleVerificationError(
                    f"{file}: {role} '{spec.name}' has size {got} on axis {axis}, the manifest implies {want}"
                )


def check_graph(path: Path, spec: GraphSpec) -> None:
    """Compare one ONNX file's declared inputs/outputs with ``spec`` (names, element types, ranks, static dims)."""
    import onnx

    try:
        model = onnx.load(str(path), load_external_data=False)
    except Exception as error:  # noqa: BLE001 - any parse failure is a bad file
        raise BundleVerificationError(f"{path.name}: not a readable ONNX model ({error})") from error
    initializers = {init.name for init in model.graph.initializer}
    inputs = [v for v in model.graph.input if v.name not in initializers]
    _check_tensors(path.name, "input", inputs, spec.inputs)
    _check_tensors(path.name, "output", list(model.graph.output), spec.outputs)


# ---------------------------------------------------------------------------------------------------- files

def sha256_of(path: Path, chunk: int = 1 << 20) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(chunk), b""):
            digest.update(block)
    return digest.hexdigest()


def check_files(bundle_dir: Path, files: Mapping[str, Any]) -> None:
    """Every required file listed; every listed file present with its recorded size and sha256."""
    for name in REQUIRED_FILES:
        if name not in files:
            raise BundleVerificationError(f"{MANIFEST_NAME}: field 'files' does not list required file '{name}'")
    for name, entry in files.items():
        if not isinstance(entry, Mapping) or not _is_str(entry.get("sha256")) or not _is_int(entry.get("bytes")):
            raise BundleVerificationError(f"{MANIFEST_NAME}: field 'files.{name}' must be {{sha256: str, bytes: int}}")
        path = bundle_dir / name
        if Path(name).is_absolute() or ".." in Path(name).parts:
            raise BundleVerificationError(f"{MANIFEST_NAME}: field 'files.{name}' must be a path inside the bundle")
        if not path.is_file():
            raise BundleVerificationError(f"{name}: listed in {MANIFEST_NAME} but missing from {bundle_dir}")
        size = path.stat().st_size
        if size != entry["bytes"]:
            raise BundleVerificationError(f"{name}: size is {size} bytes, {MANIFEST_NAME} says {entry['bytes']}")
        digest = sha256_of(path)
        if digest != entry["sha256"]:
            raise BundleVerificationError(f"{name}: sha256 is {digest}, {MANIFEST_NAME} says {entry['sha256']}")


def check_arrays_and_tokenizer(bundle_dir: Path, manifest: Mapping[str, Any]) -> None:
    """mean/std are float32 [feature_dim] (std > 0); tokenizer.json loads with the tokenizers library."""
    import numpy as np

    for name in ("mean.npy", "std.npy"):
        try:
            array = np.load(bundle_dir / name, allow_pickle=False)
        except Exception as error:  # noqa: BLE001
            raise BundleVerificationError(f"{name}: not a readable .npy array ({error})") from error
        if array.dtype != np.float32 or array.shape != (manifest["feature_dim"],):
            raise BundleVerificationError(
                f"{name}: must be float32 [{manifest['feature_dim']}], got {array.dtype} {list(array.shape)}"
            )
        if not np.all(np.isfinite(array)) or (name == "std.npy" and not np.all(array > 0)):
            raise BundleVerificationError(f"{name}: must be finite (and std > 0)")
    from tokenizers import Tokenizer

    try:
        Tokenizer.from_file(str(bundle_dir / "tokenizer.json"))
    except Exception as error:  # noqa: BLE001
        raise BundleVerificationError(f"tokenizer.json: the tokenizers library cannot load it ({error})") from error


def read_manifest(bundle_dir: Path) -> dict[str, Any]:
    path = bundle_dir / MANIFEST_NAME
    if not path.is_file():
        raise BundleVerificationError(f"{MANIFEST_NAME}: not found in {bundle_dir}")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as error:
        raise BundleVerificationError(f"{MANIFEST_NAME}: invalid JSON at line {error.lineno}: {error.msg}") from error


def verify_bundle(bundle_dir: str | Path, *, check_hashes: bool = True) -> dict[str, Any]:
    """Check a bundle directory completely; return its manifest. Raises BundleVerificationError on the first problem."""
    bundle_dir = Path(bundle_dir)
    if not bundle_dir.is_dir():
        raise BundleVerificationError(f"{bundle_dir}: not a bundle directory")
    manifest = read_manifest(bundle_dir)
    check_manifest_fields(manifest)
    if check_hashes:
        check_files(bundle_dir, manifest["files"])
    check_arrays_and_tokenizer(bundle_dir, manifest)
    for name, spec in expected_graphs(manifest).items():
        check_graph(bundle_dir / name, spec)
    return manifest


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m export.verify", description="Verify a t2m model bundle.")
    parser.add_argument("bundle", type=Path)
    args = parser.parse_args(argv)
    try:
        manifest = verify_bundle(args.bundle)
    except BundleVerificationError as error:
        print(f"bundle invalid: {error}", file=sys.stderr)
        return 2
    print(f"bundle ok: {manifest['name']} {manifest['version']} ({len(manifest['files'])} files)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
