"""write_bundle / verify_bundle / build_random_bundle: a bundle satisfies the contract, and every kind of damage
is caught with a message that names the file or manifest field."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import onnx
import pytest

from t2m.bundle import BundleError
from t2m.export.graphs.export import ort_session
from t2m.export.graphs.text import tokenize
from t2m.export.writing.bundle import prepare_out_dir, write_bundle
from t2m.export.writing.verify import main as verify_main
from t2m.export.writing.verify import verify_bundle
from t2m.families.gpt.random_bundle import build_random_bundle


def _copy(bundle: Path, tmp_path: Path) -> Path:
    target = tmp_path / "copy"
    shutil.copytree(bundle, target)
    return target


def _edit_manifest(bundle: Path, edit) -> None:
    manifest = json.loads((bundle / "manifest.json").read_text())
    edit(manifest)
    (bundle / "manifest.json").write_text(json.dumps(manifest))


def test_random_bundle_satisfies_the_contract_and_its_graphs_run(random_bundle):
    manifest = verify_bundle(random_bundle)
    assert set(manifest["files"]) == {"text_encoder.onnx", "tokenizer.json", "gpt_step.onnx", "decoder.onnx",
                                      "encoder.onnx", "mean.npy", "std.npy", "MODEL_CARD.md"}
    assert manifest["end_id"] == manifest["codebook_size"]
    gpt = manifest["gpt"]
    # text graph on tokens from the shipped tokenizer.json: unit-length features of the declared dim
    ids, mask = tokenize(random_bundle / "tokenizer.json", ["a person walks", "someone jumps up and down twice"])
    assert ids.shape[1] <= manifest["text_encoder"]["max_length"]
    (features,) = ort_session(random_bundle / "text_encoder.onnx").run(
        None, {"input_ids": ids.numpy(), "attention_mask": mask.numpy()})
    assert features.shape == (2, manifest["text_encoder"]["dim"])
    np.testing.assert_allclose(np.linalg.norm(features, axis=1), 1.0, atol=1e-5)
    # two steps of the GPT graph, starting from a zero-length cache
    step = ort_session(random_bundle / "gpt_step.onnx")
    past = np.zeros((gpt["n_layer"], 2, 2, gpt["n_head"], 0, gpt["head_dim"]), np.float32)
    for position in range(2):
        logits, past = step.run(None, {"cond": features, "token": np.array([3, 4]), "length": np.array([5, 0]),
                                       "position": np.array([position]), "past_kv": past})
        assert logits.shape == (2, manifest["codebook_size"] + 1)
        assert past.shape[4] == position + 1
    (decoded,) = ort_session(random_bundle / "decoder.onnx").run(None, {"codes": np.array([[1, 2, 3]], np.int64)})
    assert decoded.shape == (1, 3 * manifest["frames_per_token"], manifest["feature_dim"])


def test_random_bundle_is_deterministic(random_bundle, tmp_path):
    again = json.loads((build_random_bundle(tmp_path / "again") / "manifest.json").read_text())
    first = json.loads((random_bundle / "manifest.json").read_text())
    assert again["files"]["gpt_step.onnx"] == first["files"]["gpt_step.onnx"]
    assert again["files"]["decoder.onnx"] == first["files"]["decoder.onnx"]


def test_variants_without_length_input_with_residual_codes_and_int8(tmp_path):
    bundle = build_random_bundle(tmp_path / "b", length_conditioning=False, residual_layers=3, int8="all",
                                 unconditional_branch=False, default_guidance=1.0)
    manifest = verify_bundle(bundle)
    assert manifest["quantization"] == {"text_encoder": "int8-dynamic", "gpt_step": "int8-dynamic-rows"}
    names = [i.name for i in ort_session(bundle / "gpt_step.onnx").get_inputs()]
    assert names == ["cond", "token", "position", "past_kv"]
    decoder = ort_session(bundle / "decoder.onnx")
    assert len(decoder.get_inputs()[0].shape) == 3
    codes = np.array([[[1, 2, -1], [3, 4, -1]]], np.int64)  # -1: layer not used
    assert decoder.run(None, {"codes": codes})[0].shape == (1, 8, 263)
    assert "no trained unconditional branch" in (bundle / "MODEL_CARD.md").read_text()


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (lambda b: (b / "decoder.onnx").write_bytes((b / "decoder.onnx").read_bytes()[:-1] + b"\0"),
         "decoder.onnx: sha256"),
        (lambda b: (b / "mean.npy").unlink(), "mean.npy: missing file"),
        (lambda b: (b / "std.npy").write_bytes((b / "std.npy").read_bytes() + b"x"), "std.npy: size mismatch"),
        (lambda b: _edit_manifest(b, lambda m: m["gpt"].pop("n_head")), "missing field 'gpt.n_head'"),
        (lambda b: _edit_manifest(b, lambda m: m.update(format_version=2)), "field 'format_version'"),
        (lambda b: _edit_manifest(b, lambda m: m.update(end_id=7)), "field 'end_id' is 7, expected codebook_size"),
        (lambda b: _edit_manifest(b, lambda m: m["files"].pop("tokenizer.json")),
         "field 'files' does not list 'tokenizer.json'"),
        (lambda b: _edit_manifest(b, lambda m: m["gpt"].update(length_conditioning=False)),
         "gpt_step.onnx: unexpected graph inputs ['length']"),
        (lambda b: _edit_manifest(b, lambda m: m["gpt"].update(n_layer=5)),
         "gpt_step.onnx: input 'past_kv' has size 2 on axis 0, the manifest implies 5"),
        (lambda b: _edit_manifest(b, lambda m: m["text_encoder"].update(dim=16)),
         "text_encoder.onnx: output 'text_features' has size 32 on axis 1"),
        (lambda b: _edit_manifest(b, lambda m: m.update(residual_layers=2)), "decoder.onnx: input 'codes' has rank 2"),
        (lambda b: (b / "manifest.json").write_text("{\n  oops"), "manifest.json: invalid JSON at line 2"),
    ],
)
def test_damage_is_reported_with_the_file_or_field(random_bundle, tmp_path, damage, message):
    bundle = _copy(random_bundle, tmp_path)
    damage(bundle)
    with pytest.raises(BundleError, match=None) as error:
        verify_bundle(bundle)
    assert message in str(error.value)
    assert isinstance(error.value, ValueError)


def test_renamed_graph_input_is_reported(random_bundle, tmp_path):
    bundle = _copy(random_bundle, tmp_path)
    model = onnx.load(str(bundle / "decoder.onnx"))
    model.graph.input[0].name = "ids"
    for node in model.graph.node:
        node.input[:] = ["ids" if name == "codes" else name for name in node.input]
    onnx.save(model, str(bundle / "decoder.onnx"))
    manifest = json.loads((bundle / "manifest.json").read_text())
    files = {name: bundle / name for name in manifest.pop("files")}
    with pytest.raises(BundleError, match=r"decoder.onnx: graph has no input 'codes' \(has \['ids'\]\)"):
        write_bundle(bundle, files, manifest)  # re-hashing does not make a wrong graph right


def test_verify_cli_exit_codes(random_bundle, tmp_path, capsys):
    assert verify_main([str(random_bundle)]) == 0
    assert "bundle ok" in capsys.readouterr().out
    assert verify_main([str(tmp_path)]) == 2
    assert "manifest.json: missing file" in capsys.readouterr().err


def test_out_dir_with_unrelated_files_is_refused(tmp_path):
    (tmp_path / "notes.txt").write_text("mine")
    with pytest.raises(ValueError, match="refusing to overwrite"):
        prepare_out_dir(tmp_path)
    assert (tmp_path / "notes.txt").read_text() == "mine"


def test_write_bundle_rejects_paths_outside_the_bundle(tmp_path):
    with pytest.raises(ValueError, match="not allowed"):
        write_bundle(tmp_path, {"../evil.onnx": b"x"}, {})


def test_a_failed_export_leaves_the_earlier_bundle_untouched(tmp_path):
    out = build_random_bundle(tmp_path / "bundle", seed=1)
    before = (out / "manifest.json").read_text()
    with pytest.raises(ValueError, match="text encoder dim 32 != GPT text_dim 384"):
        _mismatched_export(out)
    assert (out / "manifest.json").read_text() == before
    verify_bundle(out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bundle"]  # no staging directory left behind


def _mismatched_export(out: Path) -> None:
    from t2m.export.kit.text_sources import tiny_text_source
    from t2m.families.gpt.export import export_bundle
    from t2m.families.gpt.network import GPTConfig, MotionGPT
    from t2m.model.networks.vqvae import MotionVQVAE, VQConfig

    export_bundle(out, vq=MotionVQVAE(VQConfig(width=16, code_dim=8, nb_code=32, depth=1)),
                  gpt=MotionGPT(GPTConfig(codebook_size=32, embed=32, n_head=2, n_layer_base=1, n_layer_head=1)),
                  mean=np.zeros(263, np.float32), std=np.ones(263, np.float32), text_source=tiny_text_source(32, 16),
                  name="x", version="1", unconditional_branch=True, default_guidance=3.0,
                  training_data={"name": "x", "license": "x", "attribution": ""}, license="x")
