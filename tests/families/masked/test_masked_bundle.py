"""Masked-family bundles (docs/contracts.md "The bundle", family "masked"): the tiny random builder for both
variants, the contract's refusals naming the field or file, export from training runs and `t2m export --family
masked`'s one-line errors. GPT bundles are covered unchanged by test_bundle_writer.py and tests/service."""
from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import onnx
import pytest
import torch
from onnx import TensorProto, helper

from t2m.bundle import BundleError, read_manifest, required_files
from t2m.export.writing.verify import verify_bundle
from t2m.runtime.engine import OnnxEngine
from t2m.runtime.types import GenerationRequest, SegmentRequest


@pytest.fixture(autouse=True)
def one_thread():
    torch.set_num_threads(1)


@pytest.fixture(scope="module")
def masked_2d(tmp_path_factory) -> Path:
    from t2m.families.masked.random_bundle import build_random_masked_bundle

    return build_random_masked_bundle(tmp_path_factory.mktemp("masked") / "2d", check_parity=True)


@pytest.fixture(scope="module")
def masked_1d(tmp_path_factory) -> Path:
    """MoMask's variant: one column, a single-layer VQ (no residual.onnx), no length estimator."""
    from t2m.families.masked.random_bundle import build_random_masked_bundle

    return build_random_masked_bundle(tmp_path_factory.mktemp("masked") / "1d", variant="1d", residual_layers=1,
                                      length_estimator=False)


def _copy(bundle: Path, tmp_path: Path) -> Path:
    target = tmp_path / "bundle"
    shutil.copytree(bundle, target)
    return target


def _manifest(path: Path) -> dict:
    return json.loads((path / "manifest.json").read_text())


def _write(path: Path, manifest: dict) -> None:
    (path / "manifest.json").write_text(json.dumps(manifest))


def test_the_2d_bundle_verifies_with_its_graphs_and_parity_in_the_card(masked_2d):
    manifest = verify_bundle(masked_2d)
    assert manifest["family"] == "masked"
    assert set(manifest["files"]) == {"text_encoder.onnx", "tokenizer.json", "masked.onnx", "residual.onnx",
                                      "length.onnx", "decoder.onnx", "encoder.onnx", "mean.npy", "std.npy",
                                      "MODEL_CARD.md"}
    assert "gpt" not in manifest and "end_id" not in manifest
    typed = read_manifest(masked_2d)
    assert typed.family == "masked" and type(typed.settings).__name__ == "MaskedSettings"
    assert (typed.settings.columns, typed.residual_layers, typed.settings.mask_id) == (6, 2, 16)
    assert typed.default_guidance == 4.0 and typed.unconditional_branch
    with pytest.raises(AttributeError, match="n_layer"):
        _ = typed.settings.n_layer
    card = (masked_2d / "MODEL_CARD.md").read_text()
    assert "full greedy decode" in card and "tokens identical True" in card
    assert "length estimator: max |logit diff|" in card


def test_the_1d_bundle_has_one_column_and_no_residual_or_length_graph(masked_1d):
    manifest = verify_bundle(masked_1d)
    assert manifest["masked"]["columns"] == 1 and manifest["residual_layers"] == 1
    assert not manifest["masked"]["length_estimator"]
    assert "residual.onnx" not in manifest["files"] and "length.onnx" not in manifest["files"]
    assert required_files(manifest) == ("text_encoder.onnx", "tokenizer.json", "masked.onnx", "decoder.onnx",
                                        "mean.npy", "std.npy", "MODEL_CARD.md")


def test_the_1d_residual_variant_decodes_one_column_maps(tmp_path):
    from t2m.export.graphs.export import ort_session
    from t2m.families.masked.random_bundle import build_random_masked_bundle

    bundle = build_random_masked_bundle(tmp_path / "b", variant="1d", residual_layers=2, length_estimator=False,
                                        check_parity=True)
    assert verify_bundle(bundle)["files"].keys() >= {"residual.onnx"}
    codes = np.zeros((1, 3, 1, 2), dtype=np.int64)
    (features,) = ort_session(bundle / "decoder.onnx").run(None, {"codes": codes})
    assert features.shape == (1, 12, 263)


def test_the_embedded_gpt_bundle_still_verifies():
    manifest = verify_bundle(Path(__file__).resolve().parents[3] / "t2m" / "bundles" / "gpt")
    assert manifest.get("family", "gpt") == "gpt"


@pytest.mark.parametrize("edit, message", [
    (lambda m: m["masked"].pop("steps"), "missing field 'masked.steps'"),
    (lambda m: m.pop("masked"), "missing field 'masked.columns'"),
    (lambda m: m["masked"].update(columns=0), "'masked.columns' must be a positive integer, got 0"),
    (lambda m: m["masked"].update(guidance=-1), "'masked.guidance' must be a number >= 0"),
    (lambda m: m["masked"].update(top_k=0), "'masked.top_k' must be null or a positive integer"),
    (lambda m: m["masked"].update(top_k=17), "'masked.top_k' is 17, more than codebook_size 16"),
    (lambda m: m["masked"].update(mask_id=17), "'masked.mask_id' is 17, expected codebook_size 16"),
    (lambda m: m["masked"].update(length_estimator="yes"), "'masked.length_estimator' must be true or false"),
    (lambda m: m["masked"].update(residual_temperature=0), "'masked.residual_temperature' must be null or a number"),
    (lambda m: m.update(family="flow"),
     "'family' must be one of ['diffusion', 'gpt', 'hifigpt', 'masked'], got 'flow'"),
    (lambda m: m["files"].pop("residual.onnx"), "does not list 'residual.onnx'"),
    (lambda m: (m["masked"].update(length_estimator=True), m["files"].pop("length.onnx")),
     "'masked.length_estimator' is true but 'files' does not list 'length.onnx'"),
    (lambda m: m["masked"].update(columns=5),
     "masked.onnx: input 'tokens' has size 6 on axis 2, the manifest implies 5"),
    (lambda m: m.update(residual_layers=3),
     "residual.onnx: input 'codes' has size 2 on axis 3, the manifest implies 3"),
    (lambda m: m.update(max_tokens=40), "length.onnx: output 'logits' has size 51 on axis 1, the manifest implies 41"),
])
def test_broken_masked_manifests_are_named(masked_2d, tmp_path, edit, message):
    bundle = _copy(masked_2d, tmp_path)
    manifest = _manifest(bundle)
    edit(manifest)
    _write(bundle, manifest)
    with pytest.raises(BundleError) as error:
        verify_bundle(bundle)
    assert message in str(error.value)


def test_a_missing_masked_graph_is_named(masked_2d, tmp_path):
    bundle = _copy(masked_2d, tmp_path)
    (bundle / "masked.onnx").unlink()
    with pytest.raises(BundleError, match=r"masked\.onnx: missing file"):
        verify_bundle(bundle)


def test_a_wrong_decoder_graph_is_named(masked_2d, tmp_path):
    """A 1D decoder ([B, T] codes) in a masked bundle: the rank is refused, naming the graph and input."""
    bundle = _copy(masked_2d, tmp_path)
    graph = helper.make_graph(
        [helper.make_node("Cast", ["codes"], ["features"], to=TensorProto.FLOAT)], "g",
        [helper.make_tensor_value_info("codes", TensorProto.INT64, ["b", "t"])],
        [helper.make_tensor_value_info("features", TensorProto.FLOAT, ["b", "t"])])
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], ir_version=8),
              bundle / "decoder.onnx")
    manifest = _manifest(bundle)
    data = (bundle / "decoder.onnx").read_bytes()
    manifest["files"]["decoder.onnx"] = {"sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data)}
    _write(bundle, manifest)
    with pytest.raises(BundleError, match=r"decoder\.onnx: input 'codes' has rank 2, expected 4"):
        verify_bundle(bundle)


# --- from training runs --------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def masked_runs(tmp_path_factory) -> dict[str, Path]:
    """Random tiny joint_vq / masked / residual / length runs saved as checkpoints (no training: export only reads)."""
    from t2m.families.masked.length_estimator import LengthEstimator, LengthEstimatorConfig
    from t2m.families.masked.masked_transformer import MaskedTransformer
    from t2m.families.masked.residual_transformer import ResidualTransformer
    from t2m.model.networks.joint_vqvae import JointVQConfig, JointVQVAE
    from t2m.model.networks.token_transformer import TokenTransformerConfig
    from t2m.model.networks.vqvae import MotionVQVAE, VQConfig
    from t2m.model.training.checkpoint import save_checkpoint

    root = tmp_path_factory.mktemp("runs")
    data = root / "data"
    data.mkdir()
    (data / "summary.json").write_text(json.dumps({"name": "tiny", "license": "CC0", "attribution": "tests"}))
    torch.manual_seed(0)
    runs = {name: root / name for name in ("joint_vq", "masked", "residual", "length", "gpt_vq")}
    vq = JointVQVAE(JointVQConfig(width=16, code_dim=16, nb_code=16, depth=1, residual_layers=2))
    save_checkpoint(runs["joint_vq"], vq, 1, {"data_dir": str(data)})
    rng = np.random.default_rng(0)
    np.save(runs["joint_vq"] / "mean.npy", rng.normal(0, 0.1, 263).astype(np.float32))
    np.save(runs["joint_vq"] / "std.npy", rng.uniform(0.5, 1.5, 263).astype(np.float32))
    config = TokenTransformerConfig(codebook_size=16, columns=vq.config.columns, residual_layers=2, max_tokens=20,
                                    latent=16, n_head=2, n_layer=1, ff_size=32, dropout=0.0, text_dim=32, code_dim=16)
    record = {"data_dir": str(data), "vq_run": str(runs["joint_vq"]), "training": {"cond_drop": 0.1},
              "text_encoder": {"kind": "minilm"}}
    save_checkpoint(runs["masked"], MaskedTransformer(config), 3, record)
    save_checkpoint(runs["residual"], ResidualTransformer(config), 3, record)
    save_checkpoint(runs["length"], LengthEstimator(LengthEstimatorConfig(text_dim=32, hidden=16, max_tokens=20)), 3,
                    {"data_dir": str(data)})
    save_checkpoint(runs["gpt_vq"], MotionVQVAE(VQConfig(width=16, code_dim=8, nb_code=32, depth=1)), 1)
    return runs


@pytest.fixture
def tiny_text(monkeypatch):
    from t2m.export.kit.text_sources import tiny_text_source

    monkeypatch.setattr("t2m.export.kit.text_sources.minilm_text_source", lambda: tiny_text_source(32, 32))


def test_t2m_export_family_masked_from_runs(masked_runs, tmp_path, tiny_text, capsys):
    from t2m.cli.main import main

    out = tmp_path / "bundle"
    code = main(["export", "--family", "masked", "--vq", str(masked_runs["joint_vq"]), "--masked",
                 str(masked_runs["masked"]), "--residual", str(masked_runs["residual"]), "--length",
                 str(masked_runs["length"]), "--steps", "5", "--guidance", "2.5", "--top-k", "3",
                 "--residual-top-k", "4", "-o", str(out)])
    assert code == 0
    manifest = verify_bundle(out)
    assert manifest["name"] == "t2m-tiny-masked-minilm" and manifest["license"] == "CC0"
    assert manifest["max_tokens"] == 20
    assert (manifest["masked"]["steps"], manifest["masked"]["guidance"]) == (5, 2.5)
    assert (manifest["masked"]["top_k"], manifest["masked"]["residual_top_k"]) == (3, 4)
    assert manifest["masked"]["length_estimator"] and manifest["masked"]["unconditional_branch"]
    card = (out / "MODEL_CARD.md").read_text()
    assert "tokens identical True" in card and "- length run: `length` (step 3)" in card
    assert "verified" in capsys.readouterr().out


def test_int8_text_encoder_for_the_masked_family(masked_runs, tmp_path, tiny_text, capsys):
    from t2m.cli.main import main

    out = tmp_path / "bundle"
    code = main(["export", "--family", "masked", "--vq", str(masked_runs["joint_vq"]), "--masked",
                 str(masked_runs["masked"]), "--residual", str(masked_runs["residual"]), "--int8", "text,residual",
                 "-o", str(out)])
    assert code == 0
    manifest = verify_bundle(out)
    assert manifest["quantization"] == {"text_encoder": "int8-dynamic", "residual": "int8-dynamic-rows"}
    card = (out / "MODEL_CARD.md").read_text()
    assert "- text encoder: cosine to float32 features min" in card and "tokens identical True" in card
    assert "- residual transformer: max |logit diff|" in card and "- float32: masked, decoder, length" in card
    assert "- full greedy decode with the int8 graphs vs PyTorch" in card
    engine = OnnxEngine.load(out)  # the int8 bundle serves
    motion = engine.generate(GenerationRequest([SegmentRequest("a person walks", 1.0)], seed=1, guidance=2.0))
    assert motion.joints.shape[0] == 20 and np.isfinite(motion.joints).all()
    assert '"int8"' in capsys.readouterr().out


@pytest.mark.parametrize("args, message", [
    (["--family", "masked"], "--family masked needs --masked RUN"),
    (["--masked", "{masked}"], "--masked: only with --family masked"),
    ([], "--gpt RUN is required"),
    (["--family", "masked", "--masked", "{masked}", "--gpt", "{masked}"], "--gpt: only with --family gpt"),
    (["--family", "masked", "--masked", "{masked}", "--steps", "0"], "--steps must be >= 1"),
    (["--family", "masked", "--masked", "{masked}", "--residual-top-k", "0"], "--residual-top-k must be >= 1, got 0"),
    (["--family", "masked", "--masked", "{masked}", "--int8", "gpt"], "--int8 gpt: give none, all, or some of masked"),
    (["--int8", "masked"], "--int8 masked: give none, all, or some of gpt, text"),
])
def test_wrong_export_arguments_are_one_line(masked_runs, tmp_path, capsys, args, message):
    from t2m.cli.main import main

    args = [arg.format(masked=masked_runs["masked"]) for arg in args]
    assert main(["export", "--vq", str(masked_runs["joint_vq"]), *args, "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1


@pytest.mark.parametrize("swap, message", [
    ({"masked": "residual"}, "expected a masked checkpoint, found 'residual'"),
    ({"vq": "masked"}, "--vq must be a joint_vq or vq run, found 'masked'"),
    ({"vq": "gpt_vq"}, "masked: trained on the codes of"),
])
def test_wrong_runs_are_one_line(masked_runs, tmp_path, tiny_text, capsys, swap, message):
    from t2m.cli.main import main

    runs = {"vq": masked_runs["joint_vq"], "masked": masked_runs["masked"], "residual": masked_runs["residual"]}
    runs.update({key: masked_runs[value] for key, value in swap.items()})
    code = main(["export", "--family", "masked", "--vq", str(runs["vq"]), "--masked", str(runs["masked"]),
                 "--residual", str(runs["residual"]), "-o", str(tmp_path / "o")])
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
