"""Re-check a bundle directory against the contract (t2m.bundle) with `onnx`, before it ships.

The service refuses a bad bundle at load time with the same checks (t2m.bundle); this module lets the exporter (and a
user, via ``python -m t2m.export.writing.verify DIR``) find the problems
first. It reads graph signatures with ``onnx`` (no
weights are loaded, so it is fast even for the 1 GB T2M-GPT import) and also checks mean/std and the tokenizer.
Every problem raises :class:`t2m.bundle.BundleError` naming the file or the manifest field.
"""
from __future__ import annotations

import argparse
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from t2m.bundle import (
    BundleError,
    DeclaredTensor,
    GraphSpec,
    bundle_graphs,
    check_files,
    check_graph_io,
    parse_manifest,
    read_manifest_dict,
    required_files,
)

__all__ = ["check_arrays_and_tokenizer", "check_graph", "main", "verify_bundle"]


def _declared(value_info: Any) -> DeclaredTensor:
    import onnx

    tensor_type = value_info.type.tensor_type
    dtype = onnx.helper.tensor_dtype_to_np_dtype(tensor_type.elem_type).name if tensor_type.elem_type else "?"
    dims: list[int | str | None] = [int(d.dim_value) if d.HasField("dim_value") else (d.dim_param or None)
                                    for d in tensor_type.shape.dim]
    return DeclaredTensor(value_info.name, dtype, tuple(dims))


def check_graph(path: Path, spec: GraphSpec) -> None:
    """Compare one ONNX file's declared inputs/outputs with ``spec`` (names, element types, ranks, static dims)."""
    import onnx

    try:
        model = onnx.load(str(path), load_external_data=False)
    except Exception as error:
        raise BundleError(f"{path.name}: not a readable ONNX model ({error})") from error
    initializers = {init.name for init in model.graph.initializer}
    inputs = [_declared(v) for v in model.graph.input if v.name not in initializers]
    check_graph_io(path.name, inputs, [_declared(v) for v in model.graph.output], spec)


# ---------------------------------------------------------------------------------------------------- files

def check_arrays_and_tokenizer(bundle_dir: Path, manifest: Mapping[str, Any]) -> None:
    """mean/std are float32 [feature_dim] (std > 0); tokenizer.json loads with the tokenizers library."""
    import numpy as np

    for name in ("mean.npy", "std.npy"):
        try:
            array = np.load(bundle_dir / name, allow_pickle=False)
        except Exception as error:
            raise BundleError(f"{name}: not a readable .npy array ({error})") from error
        if array.dtype != np.float32 or array.shape != (manifest["feature_dim"],):
            raise BundleError(
                f"{name}: must be float32 [{manifest['feature_dim']}], got {array.dtype} {list(array.shape)}"
            )
        if not np.all(np.isfinite(array)) or (name == "std.npy" and not np.all(array > 0)):
            raise BundleError(f"{name}: must be finite (and std > 0)")
    from tokenizers import Tokenizer

    try:
        Tokenizer.from_file(str(bundle_dir / "tokenizer.json"))
    except Exception as error:
        raise BundleError(f"tokenizer.json: the tokenizers library cannot load it ({error})") from error


def verify_bundle(bundle_dir: str | Path, *, check_hashes: bool = True) -> dict[str, Any]:
    """Check a bundle directory completely; return its manifest. Raises BundleError on the first problem."""
    bundle_dir = Path(bundle_dir)
    manifest = read_manifest_dict(bundle_dir)
    parse_manifest(manifest)
    check_files(bundle_dir, manifest["files"], check_hashes=check_hashes, required=required_files(manifest))
    check_arrays_and_tokenizer(bundle_dir, manifest)
    for name, spec in bundle_graphs(manifest).items():
        check_graph(bundle_dir / name, spec)
    return manifest


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m t2m.export.writing.verify",
                                     description="Verify a t2m model bundle.")
    parser.add_argument("bundle", type=Path)
    args = parser.parse_args(argv)
    try:
        manifest = verify_bundle(args.bundle)
    except BundleError as error:
        print(f"bundle invalid: {error}", file=sys.stderr)
        return 2
    print(f"bundle ok: {manifest['name']} {manifest['version']} ({len(manifest['files'])} files)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
