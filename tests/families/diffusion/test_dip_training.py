"""`t2m train dip` at tiny sizes: the loss falls, a resumed run repeats the uninterrupted one's
losses exactly, the exported bundle serves a request through the engine, and the export takes the EMA weights."""
from __future__ import annotations

import argparse
import csv
import json

import numpy as np
import pytest
import torch

from t2m.export.kit.text_sources import token_states_text_source
from t2m.families.diffusion import train_dip
from t2m.families.diffusion.random_bundle import TEXT_DIM, TEXT_MAX_LENGTH, TinyTokenEncoder
from t2m.families.diffusion.text_encoders import TokenStateEncoder, cache_token_states
from tests.model.synthetic_motion_data import CAPTIONS, make_dataset

torch.set_num_threads(1)


class TinyStates(torch.nn.Module):
    """TinyTokenEncoder with the token-state module's outputs (states, mask)."""

    def __init__(self, encoder: TinyTokenEncoder) -> None:
        super().__init__()
        self.encoder = encoder

    def forward(self, input_ids: torch.Tensor, attention_mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.encoder(input_ids, attention_mask), attention_mask.bool()


def tiny_encoder(tmp_path) -> TokenStateEncoder:
    """The tiny random token-state encoder, the same weights tiny_token_text_source(seed=0) exports."""
    from tokenizers import Tokenizer

    from t2m.export.graphs.text import build_tiny_tokenizer, write_tokenizer

    tokenizer = build_tiny_tokenizer()
    path = write_tokenizer(tokenizer, tmp_path / "tokenizer.json", TEXT_MAX_LENGTH, "[PAD]",
                           tokenizer.token_to_id("[PAD]"))
    module = TinyStates(TinyTokenEncoder(tokenizer.get_vocab_size(), TEXT_DIM, seed=0))
    return TokenStateEncoder("tiny-random-tokens", Tokenizer.from_file(str(path)), module, TEXT_DIM, TEXT_MAX_LENGTH)


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    root = tmp_path_factory.mktemp("dip")
    data = make_dataset(root / "data")
    (data / "summary.json").write_text(json.dumps({"name": "synthetic", "license": "CC BY 4.0",
                                                   "attribution": "test crops of HumanML3D's sample"}))
    return root, data, tiny_encoder(root)


def arguments(data, out, **overrides) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    train_dip.add_arguments(parser)
    args = parser.parse_args(["--data", str(data), "--out", str(out)])
    sizes = {"steps": 30, "batch_size": 8, "lr": 2e-3, "warmup_steps": 2, "lr_milestones": "1.0", "latent": 16,
             "layers": 1, "heads": 2, "ff_size": 32, "context_len": 8, "pred_len": 16, "min_pred_frames": 8,
             "log_every": 1, "val_every": 15, "save_every": 15, "threads": 1, "ema_decay": 0.9,
             "text_cache": str(out.parent / "tokens.npz")}
    vars(args).update({**sizes, **overrides})
    return args


def losses(run) -> list[str]:
    with (run / "log.csv").open() as handle:
        return [row["loss"] for row in csv.DictReader(handle)]


def test_the_token_state_cache_keeps_each_captions_real_tokens(setup, tmp_path):
    _, _, encoder = setup
    cache = cache_token_states(list(CAPTIONS), encoder, tmp_path / "cache.npz")
    states, mask = encoder.encode(list(CAPTIONS))
    text, text_mask = cache.batch([cache.index[c] for c in CAPTIONS])
    assert torch.equal(text_mask, torch.from_numpy(mask))
    np.testing.assert_allclose(text.numpy(), states * mask[..., None], atol=2e-3)     # float16 storage
    again = cache_token_states(list(CAPTIONS[:2]), encoder, tmp_path / "cache.npz")     # reused, not re-encoded
    assert again.texts == list(CAPTIONS[:2]) and np.array_equal(again.states, cache.states[:len(again.states)])


def test_the_loss_falls_and_the_run_records_its_model(setup):
    root, data, encoder = setup
    run = root / "falls"
    train_dip.train(arguments(data, run), encoder)
    with (run / "log.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    untrained = float(rows[0]["loss"])
    validated = [float(r["val_mse_raw"]) for r in rows if r.get("val_mse_raw")]
    assert len(validated) == 2 and validated[-1] < 0.6 * untrained, (untrained, validated)
    assert all(r.get("val_mse") for r in rows if r.get("val_mse_raw"))       # the EMA's too
    record = json.loads((run / "config.json").read_text())
    assert record["kind"] == "dip" and record["step"] == 30 and record["config"]["context_len"] == 8
    assert record["data"]["text_encoder"]["kind"] == "tiny-random-tokens"
    log = (run / "train.log").read_text()
    assert "(" in log and "trained)" in log and "step_s=" in log     # parameters trained, step time
    assert (run / "mean.npy").is_file() and (run / "curves.png").is_file()


def test_a_resumed_run_repeats_the_uninterrupted_losses_exactly(setup):
    root, data, encoder = setup
    whole, split = root / "whole", root / "split"
    train_dip.train(arguments(data, whole, steps=8, save_every=4, val_every=4), encoder)
    train_dip.train(arguments(data, split, steps=4, save_every=4, val_every=4), encoder)
    train_dip.train(arguments(data, split, steps=8, save_every=4, val_every=4, resume=True), encoder)
    assert losses(split) == losses(whole) and len(losses(whole)) == 8
    from safetensors.torch import load_file

    a, b = load_file(str(whole / "model.safetensors")), load_file(str(split / "model.safetensors"))
    assert all(torch.equal(a[k], b[k]) for k in a)      # model and model_avg alike


def test_the_export_takes_the_ema_weights_and_the_bundle_serves(setup):
    import onnxruntime as ort

    from t2m.families.diffusion.export import export_dip_from_run
    from t2m.families.diffusion.export_graphs import denoiser_inputs
    from t2m.model.training.checkpoint import load_model
    from t2m.runtime.engine import OnnxEngine
    from t2m.runtime.types import GenerationRequest, SegmentRequest

    root, _, encoder = setup
    run = root / "falls"
    net = load_model(run, expect_kind="dip")
    pairs = zip(net.model_avg.parameters(), net.model.parameters())
    assert max(float((a - p).detach().abs().max()) for a, p in pairs) > 1e-3     # the EMA lags the trained weights
    manifest, checks = export_dip_from_run(run, root / "bundle", text_source=token_states_text_source(encoder))
    assert checks["parity"]["denoiser_max_abs"] < 1e-4
    assert manifest["diffusion"]["context_len"] == 8 and manifest["diffusion"]["pred_len"] == 16
    rng = np.random.default_rng(0)
    inputs = {"x_t": rng.normal(size=(1, 16, 263)).astype(np.float32), "t": np.array([3]),
              "text": rng.normal(size=(1, 4, TEXT_DIM)).astype(np.float32), "text_mask": np.ones((1, 4), bool),
              "length": np.array([16]), "prefix": rng.normal(size=(1, 8, 263)).astype(np.float32)}
    session = ort.InferenceSession(str(root / "bundle" / "denoiser.onnx"), providers=["CPUExecutionProvider"])
    (served,) = session.run(["x0"], inputs)
    with torch.no_grad():
        given = [torch.from_numpy(inputs[n]) for n in denoiser_inputs(net.model_avg)]
        ema, trained = net.model_avg.eval()(*given).numpy(), net.model.eval()(*given).numpy()
    assert np.abs(served - ema).max() < 1e-4 < np.abs(served - trained).max()

    text = ort.InferenceSession(str(root / "bundle" / "text_encoder.onnx"), providers=["CPUExecutionProvider"])
    ids, mask = encoder.tokenize(list(CAPTIONS))
    (token_states,) = text.run(["token_states"], {"input_ids": ids.numpy(), "attention_mask": mask.numpy()})
    states, real = encoder.encode(list(CAPTIONS))                  # the graph gives what training cached
    np.testing.assert_allclose(token_states[real], states[real], atol=1e-5)

    engine = OnnxEngine.load(root / "bundle", intra_op_threads=1)
    motion = engine.generate(GenerationRequest(segments=[SegmentRequest("a person walks forward", 1.5),
                                                         SegmentRequest("a man jumps in place", 1.0)], seed=3))
    assert motion.joints.shape == (50, 22, 3) and np.isfinite(motion.joints).all()
    assert [(s.start_frame, s.end_frame) for s in motion.segments] == [(0, 30), (30, 50)]


def test_bad_options_are_refused_naming_them(setup, tmp_path):
    _, data, encoder = setup
    for overrides, name in (({"ema_decay": 1.0}, "--ema-decay"), ({"min_pred_frames": 20}, "--min-pred-frames"),
                            ({"latent": 15}, "--latent"), ({"cond_mask_prob": 1.5}, "--cond-mask-prob")):
        with pytest.raises(ValueError, match=name):
            train_dip.train(arguments(data, tmp_path / "bad", **overrides), encoder)


def test_int8_text_export_measures_its_price_and_serves(setup):
    """`t2m export --int8 text`: the token-state graph quantised, its cosine to float32 states on the card and in
    the manifest's quantization block, and the bundle verified and served."""
    import json

    from t2m.families.diffusion.export import export_dip_from_run
    from t2m.runtime.engine import OnnxEngine
    from t2m.runtime.types import GenerationRequest, SegmentRequest

    root, _, encoder = setup
    manifest, checks = export_dip_from_run(root / "falls", root / "bundle_int8", check_parity=False,
                                           text_source=token_states_text_source(encoder), int8_text=True)
    report = checks["int8"]["text_encoder"]
    assert 0.9 < report["min_cosine"] <= report["mean_cosine"] <= 1.0 + 1e-6
    assert report["int8_bytes"] < report["fp32_bytes"]
    written = json.loads((root / "bundle_int8" / "manifest.json").read_text())
    assert written["quantization"]["text_encoder"] == "int8-dynamic" == manifest["quantization"]["text_encoder"]
    assert "text encoder: cosine to float32 features" in (root / "bundle_int8" / "MODEL_CARD.md").read_text()
    motion = OnnxEngine.load(root / "bundle_int8", intra_op_threads=1).generate(
        GenerationRequest(segments=[SegmentRequest("a person walks forward", 1.0)], seed=3))
    assert motion.joints.shape == (20, 22, 3) and np.isfinite(motion.joints).all()
