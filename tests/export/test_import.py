"""`t2m import t2m-gpt` on checkpoints carrying exactly the released key names (scaled down, and full size as a
slow test): strict loads, inferred sizes, and end-to-end parity of the bundle with a PyTorch forward of the same
weights (greedy codes by full-prefix recomputation, decoded features); a served motion equal to the PyTorch
reference decode for a seed; the import served beside the default model."""
from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from beside_default import THREE_SENTENCES, check_beside_default
from served_reference import clip_features, compare_served, gpt_motion, within_rounding

from t2m.cli.main import main as t2m
from t2m.export.graphs.export import ort_session
from t2m.export.importers.kit import strip_prefix
from t2m.families.gpt.import_t2m_gpt import (
    CLIP_REQUIRED,
    import_t2m_gpt,
    infer_gpt_config,
    infer_vq_config,
    load_release,
)
from t2m.families.gpt.network import GPTConfig, MotionGPT
from t2m.families.gpt.parity import ort_greedy_rollout
from t2m.families.gpt.random_bundle import build_random_bundle
from t2m.families.gpt.t2m_gpt_release import release_gpt_state, release_vq_state, write_release_files
from t2m.model.networks.vqvae import MotionVQVAE, VQConfig
from t2m.testing.clip_release import VIT_B_32_TEXT, openai_clip_state, save_torchscript_archive

SMALL_VQ = {"width": 64, "code_dim": 32, "nb_code": 64, "down_t": 2, "depth": 3}
SMALL_GPT = {"codebook": 64, "embed": 128, "layers": (2, 2), "block": 51, "text_dim": 512}

SMALL_CLIP = {"width": 64, "layers": 2, "embed_dim": 512}  # OpenAI's vocabulary and context, T2M-GPT's 512 dims
CLIP_TEXTS = ["a person walks forward", "a man waves with the right hand \u2019", "bow " * 100]


@pytest.fixture(scope="module")
def clip_sized_text_bundle(tmp_path_factory) -> Path:
    """A bundle whose (tiny random) text graph has CLIP's 512 dims: the --text-encoder-bundle source in tests."""
    return build_random_bundle(tmp_path_factory.mktemp("text") / "b", text_dim=512, codebook_size=16)


@pytest.fixture(scope="module")
def small_clip_archive(tmp_path_factory) -> Path:
    """Random CLIP weights in the exact format of OpenAI's ViT-B-32.pt, at a small width."""
    path = tmp_path_factory.mktemp("clip") / "ViT-B-32.pt"
    return save_torchscript_archive(openai_clip_state(**SMALL_CLIP, seed=5), path)


@pytest.fixture(scope="module")
def small_release(tmp_path_factory) -> dict[str, Path]:
    vq = release_vq_state(**SMALL_VQ, seed=1)
    gpt = release_gpt_state(**SMALL_GPT, seed=2, std=0.05)
    return write_release_files(tmp_path_factory.mktemp("release"), vq, gpt)


@pytest.fixture(scope="module")
def clip_import(small_release, small_clip_archive, tmp_path_factory) -> tuple[Path, str]:
    """`t2m import t2m-gpt ... --clip ViT-B-32.pt -o OUT` (in-process): the bundle and what it printed."""
    out = tmp_path_factory.mktemp("bundle") / "t2m-gpt"
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        assert run_import(small_release, small_clip_archive, out) == 0
    return out, stdout.getvalue()


@torch.no_grad()
def reference_rollout(gpt_state: dict, config: GPTConfig, cond: np.ndarray, steps: int) -> np.ndarray:
    """T2M-GPT's way: batch 1, the whole prefix recomputed every step, greedy (End masked for a fixed length)."""
    gpt = MotionGPT(config).eval()
    gpt.load_state_dict(gpt_state, strict=True)
    codes = torch.zeros(1, 0, dtype=torch.long)
    for _ in range(steps):
        logits = gpt(torch.from_numpy(cond), codes)[:, -1, : config.codebook_size]
        codes = torch.cat([codes, logits.argmax(-1, keepdim=True)], dim=1)
    return codes.numpy()


def check_end_to_end(bundle: Path, files: dict[str, Path], vq_sizes: dict, gpt_sizes: dict, steps: int) -> float:
    """Greedy codes of the bundle's step graph identical to T2M-GPT's way of sampling; returns max |feature diff| of
    decoder.onnx vs the PyTorch decode of those codes."""
    manifest = json.loads((bundle / "manifest.json").read_text())
    gpt_state = torch.load(files["net_best_fid.pth"], weights_only=True)["trans"]
    vq_state = strip_prefix(torch.load(files["net_last.pth"], weights_only=True)["net"], "vqvae.")
    config = GPTConfig(codebook_size=gpt_sizes["codebook"], embed=gpt_sizes["embed"],
                       n_head=gpt_sizes["embed"] // 64, n_layer_base=gpt_sizes["layers"][0],
                       n_layer_head=gpt_sizes["layers"][1], block_size=gpt_sizes["block"],
                       text_dim=gpt_sizes["text_dim"], length_conditioning=False)
    cond = np.random.default_rng(3).normal(size=(1, gpt_sizes["text_dim"])).astype(np.float32)
    expected_codes = reference_rollout(gpt_state, config, cond, steps)
    g = manifest["gpt"]
    rollout = ort_greedy_rollout(ort_session(bundle / "gpt_step.onnx"), cond, np.zeros(1, np.int64),
                                 (g["n_layer"], g["n_head"], g["head_dim"]), steps, manifest["end_id"], guidance=1.0)
    np.testing.assert_array_equal(rollout.codes, expected_codes)
    assert len(set(expected_codes[0].tolist())) > 3  # a rollout that visits several codes, not one repeated

    vq = MotionVQVAE(VQConfig(**{k: vq_sizes[k] for k in ("width", "code_dim", "nb_code", "down_t", "depth")})).eval()
    vq.load_state_dict(vq_state, strict=True)
    mean, std = np.load(files["mean.npy"]), np.load(files["std.npy"])
    with torch.no_grad():
        decoded = vq.decode(torch.from_numpy(expected_codes))
        expected = (decoded * torch.from_numpy(std) + torch.from_numpy(mean)).numpy()
    (features,) = ort_session(bundle / "decoder.onnx").run(None, {"codes": expected_codes})
    assert features.shape == (1, 4 * steps, 263)
    assert np.abs(features - expected).max() <= 1e-4
    return float(np.abs(features - expected).max())


def test_release_key_names_load_strictly_with_inferred_sizes():
    vq_state = strip_prefix(release_vq_state(**SMALL_VQ), "vqvae.")
    config = infer_vq_config(vq_state)
    assert (config.width, config.code_dim, config.nb_code, config.down_t, config.depth) == (64, 32, 64, 2, 3)
    MotionVQVAE(config).load_state_dict(vq_state, strict=True)
    gpt_state = release_gpt_state(**SMALL_GPT)
    config = infer_gpt_config(gpt_state)
    assert (config.codebook_size, config.embed, config.n_head, config.n_layer_base, config.n_layer_head,
            config.block_size, config.text_dim, config.ff_rate, config.length_conditioning) == \
        (64, 128, 2, 2, 2, 51, 512, 4, False)
    MotionGPT(config).load_state_dict(gpt_state, strict=True)  # pos_embedding.weight and attn.mask accepted
    assert infer_gpt_config(gpt_state, heads=4).n_head == 4


def test_import_via_cli_gives_a_verified_bundle_matching_pytorch(small_release, clip_sized_text_bundle, tmp_path,
                                                                  capsys):
    f = small_release
    out = tmp_path / "imported"
    code = t2m(["import", "t2m-gpt", "--vq", str(f["net_last.pth"]), "--gpt", str(f["net_best_fid.pth"]),
                "--mean", str(f["mean.npy"]), "--std", str(f["std.npy"]),
                "--text-encoder-bundle", str(clip_sized_text_bundle), "-o", str(out)])
    assert code == 0, capsys.readouterr().err
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["gpt"] == {"n_layer": 4, "n_head": 2, "head_dim": 64, "block_size": 51,
                               "length_conditioning": False, "unconditional_branch": False, "default_guidance": 1.0}
    assert manifest["codebook_size"] == 64 and manifest["end_id"] == 64 and manifest["max_tokens"] == 50
    assert manifest["training_data"]["name"] == "HumanML3D"
    assert [i.name for i in ort_session(out / "gpt_step.onnx").get_inputs()] == ["cond", "token", "position", "past_kv"]
    np.testing.assert_array_equal(np.load(out / "mean.npy"), np.load(f["mean.npy"]))
    assert "assumed embed / 64" in (out / "MODEL_CARD.md").read_text()
    check_end_to_end(out, f, {**SMALL_VQ}, SMALL_GPT, steps=50)


def test_import_refuses_without_a_text_encoder(small_release, tmp_path):
    f = small_release
    with pytest.raises(ValueError, match="needs CLIP ViT-B/32 weights") as error:
        import_t2m_gpt(f["net_last.pth"], f["net_best_fid.pth"], f["mean.npy"], f["std.npy"], tmp_path / "o")
    assert str(error.value) == CLIP_REQUIRED


def test_bad_checkpoints_are_named(tmp_path, small_release, clip_sized_text_bundle):
    f = small_release
    wrong = tmp_path / "wrong.pth"
    torch.save({"model": {}}, wrong)
    kwargs = {"text_encoder_bundle": clip_sized_text_bundle}
    with pytest.raises(ValueError, match=r"wrong.pth: no key 'net'"):
        import_t2m_gpt(wrong, f["net_best_fid.pth"], f["mean.npy"], f["std.npy"], tmp_path / "o", **kwargs)
    state = torch.load(f["net_best_fid.pth"], weights_only=True)["trans"]
    del state["trans_head.head.weight"]
    torch.save({"trans": state}, wrong)
    with pytest.raises(ValueError, match=r"wrong.pth: weights do not fit.*trans_head.head.weight"):
        import_t2m_gpt(f["net_last.pth"], wrong, f["mean.npy"], f["std.npy"], tmp_path / "o", **kwargs)
    with pytest.raises(ValueError, match="--heads 3 does not divide the embedding size 128"):
        import_t2m_gpt(f["net_last.pth"], f["net_best_fid.pth"], f["mean.npy"], f["std.npy"], tmp_path / "o",
                       heads=3, **kwargs)
    import argparse

    net = torch.load(f["net_last.pth"], weights_only=True)["net"]
    torch.save({"net": net, "args": argparse.Namespace(lr=1)}, wrong)
    with pytest.raises(ValueError, match=r"wrong.pth: not loadable as plain tensors .*--allow-pickle"):
        import_t2m_gpt(wrong, f["net_best_fid.pth"], f["mean.npy"], f["std.npy"], tmp_path / "o", **kwargs)
    np.save(tmp_path / "short.npy", np.zeros(10, np.float32))
    with pytest.raises(ValueError, match=r"short.npy: expected \[263\] values"):
        import_t2m_gpt(f["net_last.pth"], f["net_best_fid.pth"], tmp_path / "short.npy", f["std.npy"],
                       tmp_path / "o", **kwargs)


def run_import(files: dict[str, Path], clip: Path, out: Path) -> int:
    return t2m(["import", "t2m-gpt", "--vq", str(files["net_last.pth"]), "--gpt", str(files["net_best_fid.pth"]),
                "--mean", str(files["mean.npy"]), "--std", str(files["std.npy"]), "--clip", str(clip), "-o", str(out)])


def check_clip_text_graph(bundle: Path, clip: Path) -> float:
    """The bundle's tokenizer.json + text_encoder.onnx vs our PyTorch tower read from the CLIP file; max |diff|."""
    from t2m.model.networks.clip_tokenizer import build_clip_tokenizer
    from t2m.model.networks.clip_weights import load_clip_text
    from t2m.runtime.bundle_loader import load_bundle
    from t2m.runtime.text import TextEncoder, load_tokenizer

    served = load_bundle(bundle)
    tokenizer = load_tokenizer(served.tokenizer_file, served.manifest.text_max_length)
    encodings = build_clip_tokenizer().encode_batch(CLIP_TEXTS)
    assert [e.ids for e in tokenizer.encode_batch(CLIP_TEXTS)] == [e.ids for e in encodings]
    features = TextEncoder(served.text_session, tokenizer).encode(CLIP_TEXTS)  # the service's own path
    with torch.no_grad():
        expected = load_clip_text(clip).encode_text(torch.tensor([e.ids for e in encodings])).numpy()
    assert features.shape == expected.shape == (len(CLIP_TEXTS), 512)
    return float(np.abs(features - expected).max())


def test_import_with_openais_clip_file_via_cli(clip_import, small_release, small_clip_archive):
    """--clip with a file in OpenAI's exact format (TorchScript archive, visual keys, float16): needs no open_clip."""
    out, printed = clip_import
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["text_encoder"] == {"kind": "clip", "dim": 512, "max_length": 77, "pooling": "eot",
                                        "normalize": False, "null_condition": "zeros"}
    report = json.loads(printed.split("\nimported T2M-GPT")[0])
    assert report["parity"]["text_encoder"]["max_abs_diff"] <= 1e-5
    assert check_clip_text_graph(out, small_clip_archive) <= 1e-5
    assert "QuickGELU" in (out / "MODEL_CARD.md").read_text()
    check_end_to_end(out, small_release, {**SMALL_VQ}, SMALL_GPT, steps=10)


def test_a_served_motion_equals_the_pytorch_reference_decode(clip_import, small_release, small_clip_archive):
    """The engine over the imported bundle vs the release's modules (load_release) through t2m.families.gpt.sampling
    with the same seed, the PyTorch VQ decode and joints; text from the PyTorch CLIP tower of the same file. Sampled
    over the whole codebook at the release's guidance 1 (not greedy): two fixed segments and one ended by End (or 50
    codes)."""
    texts = [text for text, _ in THREE_SENTENCES]
    conds = clip_features(small_clip_archive, texts)
    models = load_release(small_release["net_last.pth"], small_release["net_best_fid.pth"], small_release["mean.npy"],
                          small_release["std.npy"])
    expected = gpt_motion(models, conds, THREE_SENTENCES, seed=7, guidance=1.0)
    assert [len(c) for c in expected.codes][:2] == [10, 6] and len(np.unique(np.concatenate(expected.codes))) > 10
    diffs = compare_served(clip_import[0], THREE_SENTENCES, 7, expected, conds)
    assert within_rounding(diffs), diffs


def test_served_beside_the_default_model(clip_import):
    check_beside_default(clip_import[0])


def test_a_wrong_clip_file_is_one_line_and_checked_first(small_release, small_clip_archive, tmp_path, capsys):
    """Exit 2 with one line naming the key or shape; the CLIP file is read before the slow checkpoint loads
    (here the checkpoints do not even exist)."""
    absent = {name: tmp_path / "absent" / name for name in small_release}
    state = {k: v for k, v in openai_clip_state(**SMALL_CLIP).items() if k != "transformer.resblocks.1.ln_2.bias"}
    missing = save_torchscript_archive(state, tmp_path / "missing.pt")
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(small_clip_archive.read_bytes()[:100_000])
    cases = {missing: "missing tensor 'transformer.resblocks.1.ln_2.bias' [64]",
             truncated: "not a complete PyTorch file", small_release["net_last.pth"]: "holds a dict with keys ['net']"}
    for clip, message in cases.items():
        assert run_import(absent, clip, tmp_path / "o") == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and message in err and str(clip) in err, err


@pytest.mark.slow
def test_full_release_shapes_import_end_to_end(tmp_path, clip_sized_text_bundle, capsys):
    """228M-parameter GPT + 19.7M VQ with the release's shapes (random values): ~1 GB bundle, a few minutes. Prints
    the measured figures (docs/serving-released-models.md)."""
    vq = release_vq_state(seed=1)
    gpt = release_gpt_state(seed=2, std=0.02)
    assert len(vq) == 67 and len(gpt) == 314
    files = write_release_files(tmp_path / "release", vq, gpt)
    del vq, gpt
    out = tmp_path / "imported"
    manifest, checks = import_t2m_gpt(files["net_last.pth"], files["net_best_fid.pth"], files["mean.npy"],
                                      files["std.npy"], out, text_encoder_bundle=clip_sized_text_bundle)
    assert manifest["gpt"]["n_layer"] == 18 and manifest["gpt"]["n_head"] == 16 and manifest["gpt"]["head_dim"] == 64
    assert checks.parity["gpt_step"]["codes_identical"] and checks.parity["gpt_step"]["max_abs_logit_diff"] <= 1e-4
    end_to_end = check_end_to_end(out, files, {"width": 512, "code_dim": 512, "nb_code": 512, "down_t": 2, "depth": 3},
                                  {"codebook": 512, "embed": 1024, "layers": (9, 9), "block": 51, "text_dim": 512},
                                  steps=50)
    gpt, decoder = checks.parity["gpt_step"], checks.parity["decoder"]
    with capsys.disabled():
        print(f"\nreleased sizes: step graph vs PyTorch KV-cached step, 50-step greedy rollout: max |logit diff| "
              f"{gpt['max_abs_logit_diff']:.2e}, vs full-prefix recomputation {gpt['max_abs_diff_vs_recompute']:.2e}, "
              f"codes identical {gpt['codes_identical']}; decoder.onnx on random codes {decoder['max_abs_diff']:.2e}; "
              f"greedy codes vs T2M-GPT's batch-1 recomputation identical, their decode {end_to_end:.2e}")


@pytest.mark.slow
def test_full_vit_b_32_text_tower_through_import(small_release, tmp_path, capsys):
    """--clip at OpenAI's ViT-B/32 text sizes (width 512, 12 layers, 8 heads; random values, the release's dtypes)."""
    text = {k: VIT_B_32_TEXT[k] for k in ("width", "layers", "embed_dim")}
    clip = save_torchscript_archive(openai_clip_state(**text, seed=6), tmp_path / "ViT-B-32.pt")
    out = tmp_path / "imported"
    assert run_import(small_release, clip, out) == 0, capsys.readouterr().err
    assert check_clip_text_graph(out, clip) <= 1e-5


def test_cuda_graph_step_import_adds_the_fixed_step_with_the_same_codes(small_release, clip_sized_text_bundle,
                                                                         tmp_path, capsys):
    """`--cuda-graph-step`: gpt_step_fixed.onnx in the bundle (hashed, checked against the manifest), serving the
    release's codes through FixedCacheGptStep when T2M_CUDA_GRAPHS is on (here on the CPU provider)."""
    from t2m.runtime.engine import OnnxEngine
    from t2m.runtime.execution import Execution
    from t2m.runtime.types import GenerationRequest, SegmentRequest

    f = small_release
    out = tmp_path / "imported"
    code = t2m(["import", "t2m-gpt", "--vq", str(f["net_last.pth"]), "--gpt", str(f["net_best_fid.pth"]),
                "--mean", str(f["mean.npy"]), "--std", str(f["std.npy"]), "--skip-parity", "--cuda-graph-step",
                "--text-encoder-bundle", str(clip_sized_text_bundle), "-o", str(out)])
    assert code == 0, capsys.readouterr().err
    assert "gpt_step_fixed.onnx" in json.loads((out / "manifest.json").read_text())["files"]
    request = GenerationRequest([SegmentRequest("a person walks", 2.0)], seed=1)
    plain = OnnxEngine.load(out, intra_op_threads=1).generate(request)
    fixed_engine = OnnxEngine.load(out, intra_op_threads=1, execution=Execution(cuda_graphs=True))
    assert type(fixed_engine.codes.step).__name__ == "FixedCacheGptStep"
    np.testing.assert_array_equal(fixed_engine.generate(request).joints, plain.joints)
