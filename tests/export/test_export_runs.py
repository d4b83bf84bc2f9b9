"""`t2m export` from training runs: manifest facts come from the runs (condition dropout -> unconditional branch,
text encoder, training data + licence), the float32 graphs match PyTorch, int8 is recorded, bad input is named."""
from __future__ import annotations

import json

from export_run_fixtures import make_runs

from t2m.cli.main import main as t2m
from t2m.export.writing.verify import verify_bundle
from t2m.families.gpt.export import export_from_runs


def test_export_from_runs_writes_the_contract_manifest(exported_runs):
    bundle, stdout = exported_runs
    manifest = verify_bundle(bundle)
    assert manifest["name"] == "t2m-bandai-namco-smpl22-minilm" and manifest["version"] == "0.2.0"
    assert manifest["gpt"]["unconditional_branch"] is True and manifest["gpt"]["default_guidance"] == 3.0
    assert manifest["gpt"]["length_conditioning"] is True
    assert manifest["text_encoder"] == {"kind": "minilm", "dim": 384, "max_length": 64, "pooling": "mean",
                                        "normalize": True, "null_condition": "zeros"}
    assert manifest["training_data"]["license"] == "CC BY-NC 4.0" and manifest["license"] == "CC BY-NC 4.0"
    assert "templated from labels" in manifest["training_data"]["attribution"]
    assert manifest["quantization"] == {"text_encoder": None, "gpt_step": "int8-dynamic-rows"}
    printed = json.loads(stdout[: stdout.rindex("}") + 1])
    parity = printed["parity"]
    assert parity["gpt_step"]["codes_identical"] and parity["gpt_step"]["max_abs_logit_diff"] <= 1e-4
    assert parity["text_encoder"]["max_abs_diff"] <= 1e-4 and parity["decoder"]["max_abs_diff"] <= 1e-4
    assert printed["int8"]["gpt_step"]["int8_bytes"] < printed["int8"]["gpt_step"]["fp32_bytes"]
    card = (bundle / "MODEL_CARD.md").read_text()
    assert "Export checks" in card and "int8 dynamic quantisation" in card and "CC BY-NC 4.0" in card


def test_no_condition_dropout_means_no_unconditional_branch(tmp_path):
    from t2m.export.kit.text_sources import tiny_text_source

    vq_run, gpt_run, _ = make_runs(tmp_path, cond_drop=0.0, length_conditioning=False)
    manifest, checks = export_from_runs(vq_run, gpt_run, tmp_path / "b", text_source=tiny_text_source(384, 64),
                                        check_parity=False)
    assert manifest["gpt"]["unconditional_branch"] is False and manifest["gpt"]["default_guidance"] == 1.0
    assert manifest["gpt"]["length_conditioning"] is False
    assert checks.parity == {}


def test_bad_runs_are_named(tmp_path, capsys):
    vq_run, gpt_run, data_dir = make_runs(tmp_path)
    assert t2m(["export", "--vq", str(gpt_run), "--gpt", str(gpt_run), "-o", str(tmp_path / "o")]) == 2
    assert "expected a vq checkpoint" in capsys.readouterr().err
    assert t2m(["export", "--vq", str(vq_run), "--gpt", str(gpt_run), "--text-encoder", "clip",
                "-o", str(tmp_path / "o")]) == 2
    assert "trained with the minilm text encoder" in capsys.readouterr().err
    (data_dir / "summary.json").write_text(json.dumps({"name": "x"}))
    assert t2m(["export", "--vq", str(vq_run), "--gpt", str(gpt_run), "-o", str(tmp_path / "o")]) == 2
    assert "summary.json: field 'license' is missing" in capsys.readouterr().err
    (data_dir / "summary.json").unlink()
    assert t2m(["export", "--vq", str(vq_run), "--gpt", str(gpt_run), "-o", str(tmp_path / "o")]) == 2
    assert "file not found" in capsys.readouterr().err and not (tmp_path / "o").exists()
