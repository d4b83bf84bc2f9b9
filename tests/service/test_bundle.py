"""The service's bundle loader (t2m.runtime.bundle_loader on the t2m.bundle contract) refuses broken bundles with a
BundleError naming the file or field."""
from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import onnx
import pytest
from onnx import TensorProto, helper

from t2m.runtime.bundle_loader import BundleError, load_bundle


@pytest.fixture
def bundle_copy(random_bundle: Path, tmp_path: Path) -> Path:
    target = tmp_path / "bundle"
    shutil.copytree(random_bundle, target)
    return target


def _manifest(path: Path) -> dict:
    return json.loads((path / "manifest.json").read_text())


def _write_manifest(path: Path, manifest: dict) -> None:
    (path / "manifest.json").write_text(json.dumps(manifest))


def _replace_graph(path: Path, name: str, model: onnx.ModelProto) -> None:
    """Swap a graph and update its hash and size so that only the graph check can fail."""
    onnx.save(model, path / name)
    manifest = _manifest(path)
    data = (path / name).read_bytes()
    manifest["files"][name] = {"sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data)}
    _write_manifest(path, manifest)


def _cast_graph(input_name: str, input_shape: list, output_name: str) -> onnx.ModelProto:
    graph = helper.make_graph(
        [helper.make_node("Cast", [input_name], [output_name], to=TensorProto.FLOAT)], "g",
        [helper.make_tensor_value_info(input_name, TensorProto.INT64, input_shape)],
        [helper.make_tensor_value_info(output_name, TensorProto.FLOAT, input_shape)])
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], ir_version=8)


def test_the_random_bundle_loads(random_bundle):
    bundle = load_bundle(random_bundle)
    assert bundle.manifest.codebook_size == 32 and bundle.manifest.settings.end_id == 32
    inputs = [tensor.name for tensor in bundle.sessions["gpt_step.onnx"].get_inputs()]
    assert "length" in inputs and bundle.manifest.length_conditioning
    assert bundle.mean.shape == (263,)


def test_missing_directory(tmp_path):
    with pytest.raises(BundleError, match="does not exist"):
        load_bundle(tmp_path / "absent")


def test_missing_manifest(bundle_copy):
    (bundle_copy / "manifest.json").unlink()
    with pytest.raises(BundleError, match=r"manifest\.json: missing file"):
        load_bundle(bundle_copy)


@pytest.mark.parametrize("name", ["decoder.onnx", "tokenizer.json", "gpt_step.onnx", "text_encoder.onnx",
                                  "MODEL_CARD.md"])
def test_missing_file_is_named(bundle_copy, name):
    (bundle_copy / name).unlink()
    with pytest.raises(BundleError, match=rf"{name.replace('.', '[.]')}: missing file"):
        load_bundle(bundle_copy)


def test_sha256_mismatch_is_named(bundle_copy):
    data = bytearray((bundle_copy / "tokenizer.json").read_bytes())
    data[10] = ord("X") if data[10] != ord("X") else ord("Y")       # same size, different content
    (bundle_copy / "tokenizer.json").write_bytes(bytes(data))
    with pytest.raises(BundleError, match=r"tokenizer\.json: sha256 mismatch"):
        load_bundle(bundle_copy)
    load_bundle(bundle_copy, check_hashes=False)                    # the operator may skip hashing


def test_size_mismatch_is_named(bundle_copy):
    with (bundle_copy / "decoder.onnx").open("ab") as stream:
        stream.write(b"\0")
    with pytest.raises(BundleError, match=r"decoder\.onnx: size mismatch"):
        load_bundle(bundle_copy)


@pytest.mark.parametrize("edit, message", [
    (lambda m: m.update(format_version=2), "format_version"),
    (lambda m: m.pop("codebook_size"), "'codebook_size'"),
    (lambda m: m["gpt"].pop("n_head"), "'gpt.n_head'"),
    (lambda m: m["text_encoder"].update(dim="384"), "'text_encoder.dim' must be a positive integer, got '384'"),
    (lambda m: m.update(family="flow"), "'family' must be one of ['diffusion', 'gpt', 'hifigpt', 'masked']"),
    (lambda m: m.update(family="masked"), "missing field 'masked.columns'"),
    (lambda m: m.update(end_id=7), "end_id"),
    (lambda m: m["gpt"].update(block_size=10), "block_size"),
    (lambda m: m.update(residual_layers=2), "residual_layers"),
    (lambda m: m["gpt"].update(n_layer=3), "input 'past_kv' has size 2 on axis 0, the manifest implies 3"),
    (lambda m: m["text_encoder"].update(dim=16),
     "text_encoder.onnx: output 'text_features' has size 32 on axis 1, the manifest implies 16"),
    (lambda m: m.update(codebook_size=40, end_id=40), "'logits' has size 33 on axis 1, the manifest implies 41"),
    (lambda m: m.update(feature_dim=251), "'features' has size 263 on axis 2, the manifest implies 251"),
    (lambda m: m["files"].pop("decoder.onnx"), "does not list 'decoder.onnx'"),
])
def test_manifest_problems_are_named(bundle_copy, edit, message):
    manifest = _manifest(bundle_copy)
    edit(manifest)
    _write_manifest(bundle_copy, manifest)
    with pytest.raises(BundleError) as error:
        load_bundle(bundle_copy)
    assert message in str(error.value)


def test_graph_input_names_are_checked(bundle_copy):
    _replace_graph(bundle_copy, "decoder.onnx", _cast_graph("tokens", ["B", "T"], "features"))
    with pytest.raises(BundleError, match=r"decoder\.onnx: graph has no input 'codes'"):
        load_bundle(bundle_copy)


def test_graph_input_ranks_are_checked(bundle_copy):
    _replace_graph(bundle_copy, "decoder.onnx", _cast_graph("codes", ["T"], "features"))
    with pytest.raises(BundleError, match=r"decoder\.onnx: input 'codes' has rank 1, expected 2"):
        load_bundle(bundle_copy)


def test_graph_output_names_are_checked(bundle_copy):
    _replace_graph(bundle_copy, "text_encoder.onnx", _cast_graph("input_ids", ["B", "L"], "pooled"))
    with pytest.raises(BundleError, match=r"text_encoder\.onnx: graph has no input 'attention_mask'"):
        load_bundle(bundle_copy)


def test_unreadable_graph_is_named(bundle_copy):
    _replace_graph(bundle_copy, "gpt_step.onnx", onnx.ModelProto())
    (bundle_copy / "gpt_step.onnx").write_bytes(b"not an onnx file")
    manifest = _manifest(bundle_copy)
    manifest["files"]["gpt_step.onnx"] = {"sha256": hashlib.sha256(b"not an onnx file").hexdigest(), "bytes": 16}
    _write_manifest(bundle_copy, manifest)
    with pytest.raises(BundleError, match=r"gpt_step\.onnx: onnxruntime cannot load"):
        load_bundle(bundle_copy)


def test_bundle_error_is_a_value_error():
    assert issubclass(BundleError, ValueError)
