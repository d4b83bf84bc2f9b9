"""T2M-HiFiGPT bundles: the step graphs against the modules (a seeded guided rollout: identical codes and stops; the
graphs at any batch and cache length), the decoder over [B, T, R] codes with unused depths, and `t2m export --family
hifigpt` from runs (names, card, refusals)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from t2m.export.writing.verify import verify_bundle
from t2m.families.hifigpt.random_bundle import random_hifigpt_models

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def graphs(tmp_path_factory) -> tuple[dict, Path]:
    from t2m.families.hifigpt.export_graphs import export_residual_step, export_temporal_step

    models = random_hifigpt_models(depth=4, shared_codebook=False, seed=1)
    out = tmp_path_factory.mktemp("graphs")
    export_temporal_step(models["model"], out / "temporal_step.onnx")
    export_residual_step(models["model"], out / "residual_step.onnx")
    return models, out


@pytest.mark.parametrize("guidance", [1.0, 3.0])
def test_a_seeded_guided_rollout_is_identical_through_the_graphs(graphs, guidance):
    from t2m.families.hifigpt.export_graphs import rollout_parity

    models, out = graphs
    parity = rollout_parity(models["model"], out / "temporal_step.onnx", out / "residual_step.onnx", guidance,
                            seed=3)
    assert parity.codes_identical and parity.differing_codes == 0
    assert max(parity.max_abs_context_diff, parity.max_abs_stop_diff, parity.max_abs_logit_diff) < 1e-4
    assert parity.steps[0] == 6 and parity.steps[2] == 3   # the fixed-length segments


def test_the_step_graphs_take_any_batch_and_cache_length(graphs):
    from t2m.families.hifigpt.export_graphs import onnx_steps
    from t2m.families.hifigpt.sampling import TorchResidualGptStep, TorchTemporalStep

    models, out = graphs
    model = models["model"]
    temporal, residual = onnx_steps(model, out / "temporal_step.onnx", out / "residual_step.onnx")
    reference_t, reference_r = TorchTemporalStep(model), TorchResidualGptStep(model)
    rng = np.random.default_rng(0)
    for batch, past in ((1, 0), (5, 7)):
        cond = rng.normal(size=(batch, 32)).astype(np.float32)
        codes = rng.integers(0, 16, (batch, 4))
        length = np.arange(batch, dtype=np.int64)
        cache = rng.normal(size=(2, 2, batch, 2, past, 16)).astype(np.float32)
        for got, want in zip(temporal(cond, codes, past, length, cache), reference_t(cond, codes, past, length, cache)):
            np.testing.assert_allclose(got, want, atol=1e-5)
        inner = rng.normal(size=(1, 2, batch, 2, min(past, 3), 16)).astype(np.float32)
        context = rng.normal(size=(batch, 32)).astype(np.float32)
        code = rng.integers(0, 16, batch)
        for got, want in zip(residual(context, code, min(past, 3), inner),
                             reference_r(context, code, min(past, 3), inner)):
            np.testing.assert_allclose(got, want, atol=1e-5)


def test_the_decoder_reads_b_t_r_codes_and_unused_depths(tmp_path):
    from t2m.export.graphs.decoder import export_decoder
    from t2m.export.graphs.export import ort_session

    models = random_hifigpt_models(depth=3)
    vq, mean, std = models["vq"], models["mean"], models["std"]
    export_decoder(vq, mean, std, tmp_path / "decoder.onnx")
    session = ort_session(tmp_path / "decoder.onnx")
    codes = np.random.default_rng(0).integers(0, 16, (2, 5, 3))
    (full,) = session.run(None, {"codes": codes})
    assert full.shape == (2, 40, 263)                        # 8 frames per code
    first_only = codes.copy()
    first_only[:, :, 1:] = -1                                # the deeper depths unused: zero vectors
    (coarse,) = session.run(None, {"codes": first_only})
    with torch.no_grad():
        expected = vq.decode(torch.from_numpy(codes[:, :, :1])).numpy() * std + mean
    np.testing.assert_allclose(coarse, expected, atol=1e-4)
    assert not np.allclose(coarse, full, atol=1e-3)


# --- from training runs --------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    """A random residual VQ run and a HiFiGPT run saved as checkpoints (export only reads them)."""
    from t2m.model.training.checkpoint import save_checkpoint

    root = tmp_path_factory.mktemp("runs")
    data = root / "data"
    data.mkdir()
    (data / "summary.json").write_text(json.dumps({"name": "tiny", "license": "CC0", "attribution": "tests"}))
    models = random_hifigpt_models(depth=2, max_tokens=12)
    runs = {name: root / name for name in ("vq", "hifigpt", "other_vq")}
    save_checkpoint(runs["vq"], models["vq"], 1, {"data_dir": str(data)})
    np.save(runs["vq"] / "mean.npy", models["mean"])
    np.save(runs["vq"] / "std.npy", models["std"])
    save_checkpoint(runs["hifigpt"], models["model"], 3,
                    {"data_dir": str(data), "vq_run": str(runs["vq"]), "text_encoder": {"kind": "minilm"},
                     "training": {"cond_drop": 0.1, "corruption": 0.5}})
    save_checkpoint(runs["other_vq"], random_hifigpt_models(depth=3)["vq"], 1, {"data_dir": str(data)})
    return runs


@pytest.fixture
def tiny_text(monkeypatch):
    from t2m.export.kit.text_sources import tiny_text_source

    monkeypatch.setattr("t2m.export.kit.text_sources.minilm_text_source", lambda: tiny_text_source(32, 32))


def test_t2m_export_family_hifigpt_from_runs(runs, tmp_path, tiny_text, capsys):
    from t2m.cli.main import main

    out = tmp_path / "bundle"
    assert main(["export", "--family", "hifigpt", "--vq", str(runs["vq"]), "--hifigpt", str(runs["hifigpt"]),
                 "--guidance", "2.5", "-o", str(out)]) == 0
    manifest = verify_bundle(out)
    assert manifest["name"] == "t2m-tiny-hifigpt-minilm" and manifest["license"] == "CC0"
    assert (manifest["family"], manifest["max_tokens"], manifest["residual_layers"]) == ("hifigpt", 12, 2)
    assert manifest["hifigpt"]["default_guidance"] == 2.5 and manifest["hifigpt"]["unconditional_branch"]
    card = (out / "MODEL_CARD.md").read_text()
    assert "seeded guided rollout (guidance 2.5" in card and "codes and stops identical True" in card
    assert "- HiFiGPT run: `hifigpt` (step 3), condition dropout 0.1" in card
    assert "verified" in capsys.readouterr().out


def test_int8_step_graphs_are_measured_and_declared(runs, tmp_path, tiny_text, capsys):
    """--int8 temporal,residual: both step graphs quantised (smaller files, declared in the manifest), the decoder and
    text graphs kept float32, and the rollout with the int8 graphs measured against PyTorch into the card."""
    from t2m.cli.main import main

    out = tmp_path / "bundle"
    assert main(["export", "--family", "hifigpt", "--vq", str(runs["vq"]), "--hifigpt", str(runs["hifigpt"]),
                 "--int8", "temporal,residual", "-o", str(out)]) == 0
    manifest = verify_bundle(out)
    assert manifest["quantization"] == {"text_encoder": None, "temporal_step": "int8-dynamic-rows",
                                        "residual_step": "int8-dynamic-rows"}
    report = json.loads(capsys.readouterr().out.split("\nbundle ")[0])["int8"]
    for key in ("temporal_step", "residual_step"):
        assert report[key]["int8_bytes"] < report[key]["fp32_bytes"]
        assert report[key]["int8_bytes"] == manifest["files"][f"{key}.onnx"]["bytes"]
    rollout = report["rollout"]
    assert 0 < rollout["max_abs_logit_diff"] < 1.0, "int8 weights change the logits, a little"
    card = (out / "MODEL_CARD.md").read_text()
    assert "## int8 dynamic quantisation" in card and "temporal_step.onnx (" in card


@pytest.mark.parametrize("args, message", [
    (["--family", "hifigpt"], "--family hifigpt needs --hifigpt RUN"),
    (["--hifigpt", "{run}"], "--hifigpt: only with --family hifigpt"),
    (["--family", "hifigpt", "--hifigpt", "{run}", "--int8", "gpt"],
     "--int8 gpt: give none, all, or some of residual, temporal, text"),
    (["--family", "masked", "--masked", "{run}", "--hifigpt", "{run}"], "--hifigpt: only with --family hifigpt"),
])
def test_wrong_export_arguments_are_one_line(runs, tmp_path, capsys, args, message):
    from t2m.cli.main import main

    args = [arg.format(run=runs["hifigpt"]) for arg in args]
    assert main(["export", "--vq", str(runs["vq"]), *args, "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1


@pytest.mark.parametrize("vq, gpt, message", [
    ("vq", "vq", "expected a hifigpt checkpoint, found 'vq'"),
    ("other_vq", "hifigpt", "hifigpt: trained on the codes of"),
])
def test_wrong_runs_are_one_line(runs, tmp_path, tiny_text, capsys, vq, gpt, message):
    from t2m.cli.main import main

    assert main(["export", "--family", "hifigpt", "--vq", str(runs[vq]), "--hifigpt", str(runs[gpt]),
                 "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
