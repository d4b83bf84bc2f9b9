"""`t2m import mdm` / `t2m import dip` end to end (t2m.families.diffusion.importer) on random-weight releases
in the official layout (t2m/families/diffusion/mdm_release.py): import -> verified bundle -> served over HTTP / by the
engine -> the
ONNX denoiser against the imported PyTorch module inside a served run with the same injected noise; every refusal
one line with exit 2. Small sizes here; at the released sizes (slow) a whole seeded sampling run of the served
bundle against the PyTorch reference of the official loop (t2m.families.diffusion.sampling), MDM-50 and DiP."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from t2m.cli.main import main as t2m
from t2m.families.diffusion.distilbert_release import RELEASE as BERT_RELEASE
from t2m.families.diffusion.distilbert_release import hub_state, tiny_vocab, write_distilbert_folder
from t2m.families.diffusion.import_dip import load_dip_release
from t2m.families.diffusion.import_mdm import load_mdm_release
from t2m.families.diffusion.loop import noise_from
from t2m.families.diffusion.mdm_release import (
    RELEASE_SIZES,
    make_release,
    small_bert_folder,
    small_clip_archive,
)
from t2m.families.diffusion.sampling import TorchDenoiser, reference_chain, reference_sample
from t2m.families.diffusion.served import OnnxDenoiser
from tests.shared_data import HUMANML3D_SAMPLE

COMMAND = {"paper": "mdm", "fifty": "mdm", "bert": "mdm", "dip": "dip"}
TWO_SENTENCES = [{"text": "a person walks forward", "duration": 1.0},
                 {"text": "a person waves with the right hand", "duration": 0.75}]


@pytest.fixture(scope="module")
def encoders(tmp_path_factory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("encoders")
    return small_clip_archive(root), small_bert_folder(root)


def import_args(name: str, folder: Path, out: Path, encoders: tuple[Path, Path], *extra: str) -> list[str]:
    clip, bert = encoders
    text = ["--bert", str(bert)] if name in ("bert", "dip") else ["--clip", str(clip)]
    return ["import", COMMAND[name], str(folder), *text, "--humanml3d", str(HUMANML3D_SAMPLE), "-o", str(out),
            *extra]


@pytest.fixture(scope="module")
def imported(tmp_path_factory, encoders):
    """name -> (release folder, bundle, printed output) for the four releases, imported by the CLI."""
    import contextlib
    import io

    root = tmp_path_factory.mktemp("diffusion-imports")
    made = {}
    for name in COMMAND:
        folder, _ = make_release(root / "releases" / name, name)
        out = root / "bundles" / name
        printed = io.StringIO()
        with contextlib.redirect_stdout(printed):
            assert t2m(import_args(name, folder, out, encoders)) == 0
        made[name] = (folder, out, printed.getvalue())
    return made


def loaded(name: str, folder: Path, encoders: tuple[Path, Path]):
    clip, bert = encoders
    if name == "dip":
        return load_dip_release(folder, bert)
    return load_mdm_release(folder, bert_dir=bert) if name == "bert" else load_mdm_release(folder, clip)


@pytest.mark.parametrize("name", list(COMMAND))
def test_the_cli_writes_a_verified_bundle_with_the_releases_settings(imported, name):
    from t2m.export.writing.verify import verify_bundle

    _, bundle, printed = imported[name]
    manifest = verify_bundle(bundle)
    block = manifest["diffusion"]
    steps = {"paper": 1000, "fifty": 50, "bert": 50, "dip": 10}[name]
    assert manifest["family"] == "diffusion" and block["steps"] == steps
    assert manifest["name"] == {"paper": "mdm-humanml3d-1000steps", "fifty": "mdm-humanml3d-50steps",
                                "bert": "mdm-humanml3d-50steps-distilbert", "dip": "dip-humanml3d"}[name]
    assert block["default_guidance"] == (7.5 if name == "dip" else 2.5) and block["unconditional_branch"]
    assert block["mask_frames"] is (name in ("bert", "dip"))
    assert (block["context_len"], block["pred_len"], block["prefix"]) == (
        (20, 40, "prefix.npy") if name == "dip" else (0, 0, None))
    assert manifest["max_tokens"] == (400 if name == "dip" else 196)
    tokens = name in ("bert", "dip")
    assert manifest["text_encoder"]["kind"] == ("distilbert" if tokens else "clip")
    assert manifest["text_encoder"]["pooling"] == ("tokens" if tokens else "eot")
    assert manifest["text_encoder"]["max_length"] == (64 if tokens else 22)       # MDM: 20 BPE tokens + 2
    np.testing.assert_array_equal(np.load(bundle / "mean.npy"), np.load(HUMANML3D_SAMPLE / "Mean.npy"))
    license = manifest["license"]
    assert "MIT, Copyright (c) 2022 Guy Tevet" in license and "non-commercial" in license
    assert ("Apache-2.0" if tokens else "OpenAI CLIP ViT-B/32 (openai/CLIP): MIT") in license
    report = json.loads(printed.split("\nimported ")[0])["parity"]
    assert report["denoiser"]["max_abs_diff"] < 1e-4 and report["text_encoder"]["max_abs_diff"] < 1e-4
    assert f"imported {manifest['name']} (diffusion: " in printed and "(verified)" in printed
    card = (bundle / "MODEL_CARD.md").read_text()
    for text in ("## Imported weights", "## Exactness", "Published anchors", "## Export checks", "Mean.npy",
                 "max |x0 diff|"):
        assert text in card, text
    assert ("standing still" in card) is (name == "dip")


@pytest.mark.parametrize("name", ["fifty", "dip"])
def test_the_imported_bundle_is_served_over_http(imported, name):
    from fastapi.testclient import TestClient

    from t2m.service.app import create_app
    from t2m.service.settings import Settings
    from tests.service.conftest import wait_ready

    with TestClient(create_app(Settings(bundle_path=imported[name][1], intra_op_threads=1))) as client:
        wait_ready(client)
        served_over_http(client)


def served_over_http(client) -> None:
    health = client.get("/health").json()
    assert health["model"]["extra"]["family"] == "diffusion"
    answer = client.post("/generate", json={"segments": TWO_SENTENCES, "seed": 4})
    assert answer.status_code == 200, answer.text
    data = answer.json()
    assert np.asarray(data["frames"]).shape == (35, 22, 3) and np.isfinite(np.asarray(data["frames"])).all()
    assert [(s["start_frame"], s["end_frame"]) for s in data["segments"]] == [(0, 20), (20, 35)]
    assert client.post("/generate", json={"segments": TWO_SENTENCES, "seed": 4}).json()["frames"] == data["frames"]


def served_run(bundle: Path, denoiser=None, segments=TWO_SENTENCES, noise=None) -> tuple[np.ndarray, object]:
    """The engine's sampling of one request over the bundle's denoiser (or ``denoiser``) with injected noise (the
    given draws, else seeded ones); (normalised frames [T, F], the engine)."""
    from t2m.runtime.engine import OnnxEngine
    from t2m.runtime.types import GenerationRequest, SegmentRequest

    engine = OnnxEngine.load(bundle, intra_op_threads=1)
    codes = engine.codes
    request = GenerationRequest(segments=[SegmentRequest(s["text"], s["duration"]) for s in segments], seed=1,
                                guidance=engine.limits.default_guidance)
    job = codes.job(request, engine.text, engine.limits)
    rng = np.random.default_rng(99)
    job.noise = noise_from(noise if noise is not None else
                           (lambda shape: rng.standard_normal(shape).astype(np.float32)))
    if denoiser is not None:
        codes.denoiser = denoiser
    (parts,) = codes.sample([job], engine.limits.max_tokens, None)
    return np.concatenate(parts), engine


class ModuleAsServed(OnnxDenoiser):
    """The module where the engine has denoiser.onnx, called as the engine calls the graph (a release without
    mask_frames: once per distinct length, cropped)."""

    def __init__(self, model) -> None:
        self.module, self.masks_frames = TorchDenoiser(model), model.config.mask_frames

    def _run(self, x_t, t, text, text_mask, length, prefix):
        return self.module(x_t, t, text, text_mask, length, prefix)


@pytest.mark.parametrize("name", list(COMMAND))
def test_the_onnx_denoiser_equals_the_imported_module_inside_a_served_run(imported, encoders, name):
    """The same served run (texts from the bundle's text graph; MDM's join pass, DiP's chain) over denoiser.onnx
    and over the module the import read, same injected noise; the paper model's 1000 steps on a short request."""
    folder, bundle, _ = imported[name]
    segments = TWO_SENTENCES if name != "paper" else [{"text": "a person jumps", "duration": 0.3}]
    graph, engine = served_run(bundle, segments=segments)
    module, _ = served_run(bundle, ModuleAsServed(loaded(name, folder, encoders).model), segments)
    assert np.isfinite(graph).all() and np.abs(graph).max() > 0.1
    assert np.abs(graph - module).max() < 1e-4, np.abs(graph - module).max()
    motion = engine.generate(engine_request(segments))
    assert motion.joints.shape == (len(graph), 22, 3) and np.isfinite(motion.joints).all()


def engine_request(segments):
    from t2m.runtime.types import GenerationRequest, SegmentRequest

    return GenerationRequest(segments=[SegmentRequest(s["text"], s["duration"]) for s in segments], seed=2,
                             guidance=2.5)


def test_dip_starts_from_the_standing_prefix(imported):
    from t2m.families.diffusion.export import standing_prefix

    bundle = imported["dip"][1]
    mean, std = np.load(HUMANML3D_SAMPLE / "Mean.npy"), np.load(HUMANML3D_SAMPLE / "Std.npy")
    np.testing.assert_array_equal(np.load(bundle / "prefix.npy"), standing_prefix(mean, std, 20))


# --------------------------------------------------------------------------------------------------- refusals

def _copy(imported, name: str, target: Path) -> Path:
    shutil.copytree(imported[name][0], target)
    return target


CASES = ["no-folder", "no-clip", "clip-file", "no-bert", "bert-dir", "dip-no-bert", "dip-to-mdm", "mdm-to-dip",
         "clip-for-bert", "bert-for-clip", "no-stats", "evaluator-stats", "no-mean", "stats-shape", "weights",
         "args"]


@pytest.mark.parametrize("case", CASES)
def test_refusals_are_one_line(case, imported, encoders, tmp_path, capsys):
    clip, bert = encoders
    paper, dip = imported["paper"][0], imported["dip"][0]
    stats = ["--humanml3d", str(HUMANML3D_SAMPLE)]
    out = ["-o", str(tmp_path / "out")]
    args, message = {
        "no-folder": (["mdm", str(tmp_path / "nowhere"), "--clip", str(clip), *stats],
                      f"{tmp_path / 'nowhere'}: no such folder"),
        "no-clip": (["mdm", str(paper), *stats], "MDM's text encoder is CLIP ViT-B/32 (args.json: text_encoder_type "
                                                 "'clip'): pass --clip ViT-B-32.pt"),
        "clip-file": (["mdm", str(paper), "--clip", str(tmp_path / "ViT-B-32.pt"), *stats],
                      f"{tmp_path / 'ViT-B-32.pt'}: missing file: CLIP ViT-B/32 weights"),
        "no-bert": (["mdm", str(imported["bert"][0]), *stats], "MDM's text encoder is DistilBERT (args.json: "
                                                               "text_encoder_type 'bert'): pass --bert DIR"),
        "bert-dir": (["dip", str(dip), "--bert", str(tmp_path / "bert"), *stats], f"{tmp_path / 'bert'}: no such "
                                                                                   "folder"),
        "dip-no-bert": (["dip", str(dip), *stats], "DiP's text encoder is DistilBERT"),
        "dip-to-mdm": (["mdm", str(dip), "--bert", str(bert), *stats],
                       "context_len 20: a DiP release (prefix completion); import it with t2m import dip"),
        "mdm-to-dip": (["dip", str(imported["bert"][0]), "--bert", str(bert), *stats],
                       "context_len 0: not a DiP release (no prefix completion); import it with t2m import mdm"),
        "clip-for-bert": (["mdm", str(imported["bert"][0]), "--clip", str(clip), *stats],
                          f"--clip {clip}: MDM's text encoder is DistilBERT"),
        "bert-for-clip": (["mdm", str(paper), "--clip", str(clip), "--bert", str(bert), *stats],
                          f"--bert {bert}: MDM's text encoder is CLIP ViT-B/32"),
        "no-stats": (["mdm", str(paper), "--clip", str(clip)], "no generation statistics: pass --humanml3d DIR"),
        "evaluator-stats": (["mdm", str(paper), "--clip", str(clip), *stats, "--mean", str(tmp_path / "t2m_mean.npy")],
                            "t2m_mean.npy: the evaluator's statistics"),
        "no-mean": (["dip", str(dip), "--bert", str(bert), "--humanml3d", str(tmp_path)],
                   f"{tmp_path / 'Mean.npy'}: missing file: HumanML3D's Mean.npy"),
        "stats-shape": (["mdm", str(paper), "--clip", str(clip), *stats, "--std", str(tmp_path / "std.npy")],
                        "std.npy: expected [263] values (HumanML3D's features), got [251]"),
        "weights": (["mdm", str(_copy(imported, "paper", tmp_path / "two")), "--clip", str(clip), *stats],
                    "2 weights files (model000200000.pt, model000400000.pt): pass --model FILE"),
        "args": (["dip", str(dip), "--bert", str(bert), "--clip", str(clip), *stats],
                 "unrecognized arguments: --clip"),
    }[case]
    if case == "stats-shape":
        np.save(tmp_path / "std.npy", np.ones(251, np.float32))
    if case == "weights":
        shutil.copy(tmp_path / "two" / "model000200000.pt", tmp_path / "two" / "model000400000.pt")
    try:
        code = t2m(["import", *args, *out])
    except SystemExit as exit:          # argparse's own refusals
        code = exit.code
    err = capsys.readouterr().err.strip()
    assert code == 2 and "Traceback" not in err, err
    if case == "args":      # argparse's own: the usage, then one error line naming the option
        assert message in err.splitlines()[-1], err
    else:
        assert err.count("\n") == 0 and message in err, err
    assert not (tmp_path / "out" / "manifest.json").exists()


def test_a_dip_folder_with_model_option_and_skip_parity(imported, encoders, tmp_path, capsys):
    """--model names the weights file; --skip-parity leaves the parity out of the card."""
    folder = _copy(imported, "dip", tmp_path / "dip")
    weights = folder / "model000200000.pt"
    shutil.copy(weights, folder / "model000600343.pt")
    out = tmp_path / "out"
    assert t2m(["import", "dip", str(folder), "--bert", str(encoders[1]), "--model", str(weights), "--humanml3d",
                str(HUMANML3D_SAMPLE), "--skip-parity", "--name", "dip-test", "-o", str(out)]) == 0
    card = (out / "MODEL_CARD.md").read_text()
    assert "`dip/model000200000.pt`" in card and "## Export checks" not in card
    assert json.loads((out / "manifest.json").read_text())["name"] == "dip-test"


# ------------------------------------------------------------------------------------------ released sizes

def noise_draws(seed: int, shapes: list[tuple[int, int]]) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.standard_normal(shape).astype(np.float32) for shape in shapes]


@pytest.mark.slow
@pytest.mark.parametrize("name", ["fifty", "dip"])
def test_released_sizes_a_whole_seeded_run_equals_the_reference_loop(name, tmp_path, capsys):
    """MDM-50 (17,880,327 parameters, CLIP at a small size) and DiP (26,424,583, EMA, DistilBERT at its released
    sizes, small vocabulary) imported by the CLI; one request through the served bundle (text graph, denoiser.onnx,
    the numpy loop) vs t2m.families.diffusion.sampling's torch loop over the imported modules (texts from the PyTorch
    encoders), the same injected noise: MDM one 6 s sentence (120 frames, 50 steps, guidance 2.5), DiP two
    sentences of 2 and 1.5 s (two calls of 10 steps, guidance 7.5, from the bundle's standing prefix)."""
    clip = small_clip_archive(tmp_path)
    vocab = tiny_vocab()
    sizes = BERT_RELEASE | {"vocab_size": len(vocab)}
    bert = write_distilbert_folder(tmp_path / "bert", sizes, vocab, weights="pytorch_model.bin",
                                   state=hub_state(sizes, mlm_head=False, prefix=""))
    folder, _ = make_release(tmp_path / name, name, RELEASE_SIZES)
    out = tmp_path / "bundle"
    assert t2m(import_args(name, folder, out, (clip, bert))) == 0
    parity = json.loads(capsys.readouterr().out.split("\nimported ")[0])["parity"]
    release = loaded(name, folder, (clip, bert))
    model, text = release.model, release.text
    if name == "fifty":
        segments = [{"text": "a person walks forward and turns around", "duration": 6.0}]
        draws = noise_draws(7, [(120, 263)] * 51)
        served, _ = served_run(out, segments=segments, noise=draws)
        cond = torch.from_numpy(text.encode([segments[0]["text"]]))
        reference = reference_sample(model, cond, 120, guidance=2.5,
                                     noise=iter(torch.from_numpy(d)[None] for d in draws))[0].numpy()
    else:
        segments = [{"text": "a person walks forward", "duration": 2.0},
                    {"text": "a person waves with the right hand", "duration": 1.5}]
        draws = noise_draws(7, [(40, 263)] * 22)
        served, _ = served_run(out, segments=segments, noise=draws)
        encoded = [text.encode([s["text"]]) for s in segments]
        prefix = torch.from_numpy(np.load(out / "prefix.npy"))[None]
        reference = reference_chain(model, [torch.from_numpy(states) for states, _ in encoded], prefix, 70,
                                    guidance=7.5, text_masks=[torch.from_numpy(mask) for _, mask in encoded],
                                    noise=iter(torch.from_numpy(d)[None] for d in draws))[0].numpy()
    diff = float(np.abs(served - reference).max())
    scale = float(np.abs(reference).max())
    with capsys.disabled():
        print(f"\n{name} at released sizes, whole seeded run served vs the torch reference loop: max |diff| "
              f"{diff:.2e} (values up to {scale:.2f}); import parity {parity}")
    assert served.shape == reference.shape == ((120, 263) if name == "fifty" else (70, 263))
    assert diff <= 1e-3 * max(1.0, scale)
