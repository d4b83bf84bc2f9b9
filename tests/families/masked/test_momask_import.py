"""`t2m import momask` on random-weight checkpoints in the release's exact layout
(t2m/families/masked/momask_release.py), compared
with an independent re-implementation of MoMask's computation (tests/families/masked/momask_reference.py): logits of
the loaded modules and of the bundle's graphs, token maps of the service's loop over the bundle vs MoMask's
``generate`` at top-k 1, decoded features vs the reference RVQ decode; the CLI end to end into a served bundle; one
line for each refusal; a served motion equal to the PyTorch reference decode at the release's settings for a seed;
the import served beside the default model. Small sizes here; the released sizes in the slow test."""
from __future__ import annotations

import dataclasses
import json
import logging
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from momask_reference import (
    ReferenceMaskTransformer,
    ReferenceResidualTransformer,
    generate_mask_stage,
    generate_residual_stage,
    remask_count,
    rvq_decode,
)

from t2m.cli.main import main as t2m
from t2m.export.graphs.export import ort_session
from t2m.families.masked.import_momask import import_momask, load_momask, release_decoding, release_top_k
from t2m.families.masked.loop import remask_counts
from t2m.families.masked.momask_files import kit_fps_note, locate_release
from t2m.families.masked.momask_release import RELEASE, SMALL, MomaskSizes, ReleaseStates, release_states, write_release
from t2m.families.masked.sampling import generate_token_maps
from t2m.runtime.types import GenerationRequest, SegmentRequest
from t2m.testing.clip_release import openai_clip_state, save_torchscript_archive
from tests.export.beside_default import THREE_SENTENCES, check_beside_default
from tests.export.served_reference import Generator, clip_features, compare_served, masked_motion, within_rounding

SMALL_CLIP = {"width": 64, "layers": 2, "embed_dim": 512}   # MoMask's 512-d text features, a small tower
LENGTHS = [49, 37, 12, 7, 2, 1]                                # token rows; odd ones hit the schedule's exact halves
STREAM = [("a person walks forward", 1.6), ("a person waves with the right hand", 1.0)]


@dataclasses.dataclass
class Release:
    root: Path
    states: ReleaseStates
    sizes: MomaskSizes
    files: dict[str, Path]


def make_release(root: Path, sizes: MomaskSizes = SMALL, **options) -> Release:
    """Weights at std 0.7 / sqrt(width) (0.1 at the small width: peaked attention, so the padding and position paths
    matter; confidences apart by more than float rounding, as in a trained model rather than a saturated random
    one) and a PE that is not the sinusoid (only the checkpoint's table reproduces it)."""
    states = release_states(sizes, pe_noise=0.1, std=0.7 / math.sqrt(sizes.latent))
    return Release(root, states, sizes, write_release(root, states, **options))


@pytest.fixture(scope="module")
def release(tmp_path_factory) -> Release:
    return make_release(tmp_path_factory.mktemp("momask") / "checkpoints" / "t2m")


@pytest.fixture(scope="module")
def clip_archive(tmp_path_factory) -> Path:
    """Random CLIP weights in the exact format of OpenAI's ViT-B-32.pt, at a small width."""
    return save_torchscript_archive(openai_clip_state(**SMALL_CLIP, seed=5),
                                    tmp_path_factory.mktemp("clip") / "ViT-B-32.pt")


@pytest.fixture(scope="module")
def imported(release, clip_archive, tmp_path_factory) -> tuple[Path, str]:
    """`t2m import momask CHECKPOINTS --clip ViT-B-32.pt -o OUT` (in-process): the bundle and what it printed."""
    import contextlib
    import io

    out = tmp_path_factory.mktemp("bundle") / "momask"
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        code = t2m(["import", "momask", str(release.root), "--clip", str(clip_archive), "-o", str(out)])
    assert code == 0
    return out, stdout.getvalue()


def reference_models(release: Release) -> tuple[ReferenceMaskTransformer, ReferenceResidualTransformer]:
    s = release.sizes
    masked = ReferenceMaskTransformer(s.nb_code, s.code_dim, s.latent, s.heads, s.layers, s.ff, s.text_dim, s.pe_rows)
    residual = ReferenceResidualTransformer(s.nb_code, s.code_dim, s.quantizers, s.latent, s.heads, s.layers, s.ff,
                                            s.text_dim, s.pe_rows)
    masked.load_state_dict(release.states.masked, strict=True)
    residual.load_state_dict(release.states.residual, strict=True)
    return masked.eval(), residual.eval()


def logit_inputs(s: MomaskSizes, seed: int = 0) -> dict[str, torch.Tensor]:
    """A batch of three lengths (the last two padded), a null text row and random codes (some masked / unused)."""
    g = torch.Generator().manual_seed(seed)
    lengths = torch.tensor([49, 37, 5])
    text = torch.randn(3, s.text_dim, generator=g)
    text[2] = 0.0
    ids = torch.randint(0, s.nb_code + 1, (3, 49), generator=g)        # nb_code = the mask id
    codes = torch.randint(-1, s.nb_code, (3, 49, s.quantizers), generator=g)
    return {"lengths": lengths, "text": text, "ids": ids, "codes": codes, "layer": torch.tensor([1, 3, 5])}


@torch.no_grad()
def reference_logits(release: Release, x: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
    """MoMask's forward passes on logit_inputs: mask-stage logits [B, T, K], residual logits [B, T, K + 1]."""
    masked, residual = reference_models(release)
    padding = torch.arange(49)[None] >= x["lengths"][:, None]
    ids = torch.where(padding, masked.pad_id, x["ids"])
    codes = torch.where(x["codes"] < 0, residual.pad_id, x["codes"])
    tables = residual.input_tables()
    history = sum(tables[k][codes[..., k]] * (k < x["layer"]).float()[:, None, None] for k in range(5))
    assert isinstance(history, torch.Tensor)
    return masked(ids, x["text"], padding), residual(history, x["layer"], x["text"], padding)


def max_real_diff(actual: np.ndarray, expected: np.ndarray, lengths: torch.Tensor) -> float:
    return max(float(np.abs(actual[b, :n] - expected[b, :n]).max()) for b, n in enumerate(lengths.tolist()))


def within(diffs: dict[str, float], scales: dict[str, float], tolerance: float = 1e-5) -> bool:
    """Each max |diff| at most tolerance x the largest |logit| (float32 rounding grows with the logits' size)."""
    return all(diffs[key] <= tolerance * max(1.0, scales[key]) for key in diffs)


def logit_scales(release: Release) -> dict[str, float]:
    masked, residual = reference_logits(release, logit_inputs(release.sizes))
    return {"masked": float(masked.abs().max()), "residual": float(residual.abs().max())}


def check_module_logits(release: Release) -> dict[str, float]:
    models = load_momask(locate_release(release.root, {}))
    x = logit_inputs(release.sizes)
    expected_masked, expected_residual = (t.numpy() for t in reference_logits(release, x))
    with torch.no_grad():
        masked = models.masked(x["ids"][..., None], x["text"], x["lengths"])[:, :, 0].numpy()
        residual = models.residual(x["codes"][:, :, None], x["layer"], x["text"], x["lengths"])[:, :, 0].numpy()
    return {"masked": max_real_diff(masked, expected_masked, x["lengths"]),
            "residual": max_real_diff(residual, expected_residual, x["lengths"])}


def check_graph_logits(release: Release, bundle: Path) -> dict[str, float]:
    x = logit_inputs(release.sizes, seed=1)
    expected_masked, expected_residual = (t.numpy() for t in reference_logits(release, x))
    feeds = {"cond": x["text"].numpy(), "length": x["lengths"].numpy()}
    (masked,) = ort_session(bundle / "masked.onnx").run(None, {"tokens": x["ids"][..., None].numpy(), **feeds})
    (residual,) = ort_session(bundle / "residual.onnx").run(
        None, {"codes": x["codes"][:, :, None].numpy(), "layer": x["layer"].numpy(), **feeds})
    return {"masked": max_real_diff(masked[:, :, 0], expected_masked, x["lengths"]),
            "residual": max_real_diff(residual[:, :, 0], expected_residual, x["lengths"])}


def served_token_maps(bundle: Path, lengths: list[int], seed: int = 3) -> tuple[list[np.ndarray], np.ndarray]:
    """The service's engine on one request with a segment per length (duration = rows * 4 / 20 s), top-k 1 on both
    stages: (each segment's map [rows, 1, 6], the text features it used)."""
    from t2m.runtime.engine import OnnxEngine

    engine = OnnxEngine.load(bundle, intra_op_threads=1)
    codes = engine.codes
    assert hasattr(codes, "settings")
    codes.settings = dataclasses.replace(codes.settings, residual_top_k=1)
    texts = [f"a person does motion number {i}" for i in range(len(lengths))]
    decoded: list[np.ndarray] = []
    original = engine.decoder.decode
    engine.decoder.decode = lambda maps: decoded.append(np.asarray(maps)) or original(maps)  # type: ignore[method-assign]
    request = GenerationRequest(segments=[SegmentRequest(t, n * 4 / 20) for t, n in zip(texts, lengths)], seed=seed,
                                guidance=engine.limits.default_guidance, top_k=1)
    engine.generate(request)
    splits = np.cumsum(lengths)[:-1]
    return np.split(decoded[0], splits), engine.text.encode(texts)


def reference_token_maps(release: Release, conds: np.ndarray, lengths: list[int], top_k: int = 1) -> list[np.ndarray]:
    """MoMask's two generate loops, one motion at a time (batch 1, as gen_t2m.py with one prompt), at the release's
    settings: 10 steps, guidance 4 then 5."""
    masked, residual = reference_models(release)
    maps = []
    for cond, rows in zip(conds, lengths):
        text, length = torch.from_numpy(cond[None]), torch.tensor([rows])
        ids = generate_mask_stage(masked, text, length, steps=10, scale=4.0, top_k=top_k)
        maps.append(generate_residual_stage(residual, ids, text, length, scale=5.0, top_k=top_k)[0, :, None].numpy())
    return maps


def check_decode(release: Release, bundle: Path, maps: list[np.ndarray]) -> float:
    """decoder.onnx vs the reference RVQ decode + de-normalisation, per map."""
    session, worst = ort_session(bundle / "decoder.onnx"), 0.0
    vq = release.states.vq
    mean, std = torch.from_numpy(release.states.mean), torch.from_numpy(release.states.std)
    for token_map in maps:
        (features,) = session.run(None, {"codes": token_map[None]})
        expected = rvq_decode(vq, torch.from_numpy(token_map[None, :, 0]), mean, std).numpy()
        assert features.shape == expected.shape == (1, 4 * len(token_map), release.sizes.feat_dim)
        worst = max(worst, float(np.abs(features - expected).max()))
    return worst


# ------------------------------------------------------------------------------------------------------- tests


def test_the_release_layout_loads_strictly_with_inferred_sizes(release):
    models = load_momask(locate_release(release.root, {}))
    m, r, v = models.masked.config, models.residual.config, models.vq.config
    assert (m.latent, m.n_head, m.n_layer, m.ff_size, m.text_dim, m.code_dim, m.codebook_size, m.max_tokens) == \
        (48, 6, 2, 64, 512, 32, 64, 49)
    assert (r.residual_layers, r.share_weight, v.residual_layers, v.nb_code, v.width) == (6, True, 6, 64, 32)
    assert models.length is not None and models.length.config.max_tokens == 49
    assert models.keys == {"vq": "vq_model", "masked": "t2m_transformer", "residual": "res_transformer",
                           "length": "estimator"}
    # the checkpoint's positional table (not the sinusoid: the helper perturbs it), its first 49 rows
    torch.testing.assert_close(models.masked.position_enc.pe, release.states.masked["position_enc.pe"][:49],
                               rtol=0, atol=0)
    np.testing.assert_array_equal(models.mean, release.states.mean)


def test_loaded_modules_compute_momasks_logits(release):
    diffs = check_module_logits(release)
    assert within(diffs, logit_scales(release)), diffs


def test_the_schedule_is_torchs_float32_one():
    """remask_counts vs MoMask's torch arithmetic for every length and both step counts of the release (10, 18)."""
    for steps in (10, 18):
        for length in range(1, 50):
            expected = [int(remask_count(tau, torch.tensor(length))) for tau in torch.linspace(0, 1, steps)]
            assert remask_counts(length, steps) == expected, (steps, length)


def test_top_k_and_settings_are_the_releases():
    assert (release_top_k(512), release_top_k(513), release_top_k(30), release_top_k(64)) == (52, 52, 3, 7)
    assert release_decoding("HumanML3D", 512) == release_decoding("HumanML3D", 512)
    assert dataclasses.asdict(release_decoding("HumanML3D", 512)) == {
        "steps": 10, "guidance": 4.0, "residual_guidance": 5.0, "top_k": 52, "residual_top_k": 52,
        "residual_temperature": 1.0, "temperature": None}
    assert release_decoding("KIT-ML", 512).guidance == 2.0


def test_cli_import_gives_a_verified_bundle_with_the_release_settings(imported):
    from t2m.export.writing.verify import verify_bundle

    bundle, printed = imported
    manifest = verify_bundle(bundle)
    assert manifest["family"] == "masked" and manifest["name"] == "momask-humanml3d"
    assert manifest["masked"] == {"columns": 1, "steps": 10, "guidance": 4.0, "residual_guidance": 5.0, "top_k": 7,
                                  "residual_top_k": 7, "mask_id": 64, "pad_id": 64, "unconditional_branch": True,
                                  "length_estimator": True, "residual_temperature": 1.0}
    assert (manifest["max_tokens"], manifest["residual_layers"], manifest["codebook_size"]) == (49, 6, 64)
    assert manifest["text_encoder"]["kind"] == "clip" and manifest["text_encoder"]["dim"] == 512
    assert manifest["training_data"]["name"] == "HumanML3D" and "MIT" in manifest["license"]
    report = json.loads(printed.split("\nimported MoMask")[0])["parity"]
    assert report["decode"]["tokens_identical"] and report["masked"]["max_abs_diff"] <= 1e-5
    card = (bundle / "MODEL_CARD.md").read_text()
    for text in ("t2m_nlayer8_nhead6_ld384_ff1024_cdp0.1_rvq6ns/model/latest.tar", "`t2m_transformer`",
                 "6 attention heads (the release value", "## Exactness", "Not reproducible", "non-commercial",
                 "temperature 1", "top-k 7 of 64"):
        assert text in card, text


def test_the_bundles_graphs_compute_momasks_logits(release, imported):
    diffs = check_graph_logits(release, imported[0])
    assert within(diffs, logit_scales(release)), diffs


def test_the_service_gives_momasks_token_maps_and_motion(release, imported):
    """The engine over the bundle (top-k 1: deterministic) vs MoMask's generate loops, map for map, then decode."""
    bundle = imported[0]
    served, conds = served_token_maps(bundle, LENGTHS)
    expected = reference_token_maps(release, conds, LENGTHS)
    for rows, got, want in zip(LENGTHS, served, expected):
        np.testing.assert_array_equal(got, want, err_msg=f"length {rows}")
    assert len(np.unique(expected[0][:, 0, 0])) > 3 and len(np.unique(expected[0])) > 20   # many codes
    masked, _ = reference_models(release)
    one_step = generate_mask_stage(masked, torch.from_numpy(conds[:1]), torch.tensor([49]), steps=1, scale=4.0,
                                   top_k=1)
    assert (one_step[0].numpy() != expected[0][:, 0, 0]).any()      # re-masking changed tokens: the steps are tested
    assert check_decode(release, bundle, expected) <= 1e-4


def test_a_pad_drawn_by_the_residual_stage_is_an_unused_layer(tmp_path):
    """A release whose residual stage prefers pad at layer 2: -1 there, and the pad embedding enters layer 3's
    input, in the loop exactly as in MoMask's generate."""
    release = make_release(tmp_path / "t2m", length=False)
    s, states = release.sizes, release.states
    direction = torch.randn(s.code_dim, generator=torch.Generator().manual_seed(9))
    direction = 10 * direction / direction.norm()
    states.residual["output_process.poseFinal.bias"] = states.residual["output_process.poseFinal.bias"] + direction
    states.residual["embed_proj_shared_weight"][1, s.nb_code] = direction        # W_2 = E_2: the pad row
    torch.save({"res_transformer": states.residual, "ep": 1}, release.files["residual"])
    models = load_momask(locate_release(release.root, {}))
    conds = np.random.default_rng(4).normal(size=(3, 512)).astype(np.float32)
    lengths = [9, 4, 1]
    expected = reference_token_maps(release, conds, lengths)
    assert all((m[:, 0, 2] == -1).all() for m in expected) and (expected[0][:, 0, 3] >= 0).any()
    for rows, cond, want in zip(lengths, conds, expected):
        got = generate_token_maps(models.masked, models.residual, cond[None], [rows], steps=10, guidance=4.0,
                                  residual_guidance=5.0, top_k=1, residual_top_k=1, rng=0)
        np.testing.assert_array_equal(got[0], want)


def test_the_imported_bundle_serves_a_stream(imported):
    """Served beside nothing else, through the API: a 2-sentence stream, and a free-length segment."""
    from fastapi.testclient import TestClient

    from t2m.service.app import create_app
    from t2m.service.settings import Settings
    from tests.service.conftest import wait_ready

    with TestClient(create_app(Settings(bundle_path=imported[0], intra_op_threads=1))) as client:
        wait_ready(client)
        body = {"segments": [{"text": text, "duration": duration} for text, duration in STREAM], "seed": 3}
        answer = client.post("/generate", json=body)
        assert answer.status_code == 200, answer.text
        data = answer.json()
        assert np.asarray(data["frames"]).shape == (52, 22, 3)       # 8 + 5 token rows of 4 frames
        assert [s["end_frame"] for s in data["segments"]] == [32, 52]
        assert data["model"]["name"] == "momask-humanml3d"
        free = client.post("/generate", json={**body, "segments": [*body["segments"][:1],
                                                                     {"text": "a person bows", "duration": None}]})
        assert free.status_code == 200, free.text


def test_a_served_motion_equals_the_pytorch_reference_decode(release, clip_archive, imported):
    """The engine over the imported bundle vs the release's modules (load_momask) through the shared loop with the
    same seed at the release's settings (sampled: top-k 7 of 64 here, 52 of 512 released; guidance 4 / 5; the third
    segment's rows drawn from the length estimator), the PyTorch RVQ decode and joints; text from the PyTorch CLIP
    tower of the same file."""
    conds = clip_features(clip_archive, [text for text, _ in THREE_SENTENCES])
    models = load_momask(locate_release(release.root, {}))
    decoding = release_decoding("HumanML3D", models.vq.config.nb_code)
    expected = masked_motion([Generator(models.masked, models.residual, decoding.top_k, decoding.residual_top_k)],
                             decoding, models.vq, models.mean, models.std, models.length, conds, THREE_SENTENCES,
                             seed=7, max_tokens=models.masked.config.max_tokens)
    assert [len(c) for c in expected.codes][:2] == [10, 6] and len(np.unique(expected.codes[0][..., 0])) > 5
    diffs = compare_served(imported[0], THREE_SENTENCES, 7, expected, conds)
    assert within_rounding(diffs), diffs


def test_served_beside_the_default_model(imported):
    check_beside_default(imported[0])


def test_without_the_length_estimator_one_warning_and_no_free_length(tmp_path, clip_archive, caplog):
    release = make_release(tmp_path / "t2m", length=False)
    with caplog.at_level(logging.WARNING):
        manifest, _ = import_momask(release.root, tmp_path / "out", clip_weights=clip_archive, check_parity=False)
    missing = release.root / "length_estimator" / "model" / "finest.tar"
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and str(missing) in warnings[0] and "free length" in warnings[0]
    assert manifest["masked"]["length_estimator"] is False and "length.onnx" not in manifest["files"]
    assert f"{missing}: missing file: the length estimator, needed for free length" in \
        (tmp_path / "out" / "MODEL_CARD.md").read_text()


def test_the_other_top_level_keys_and_explicit_files(release, tmp_path):
    """A best-FID copy of the mask transformer under 'trans' and the VQ under 'net', named by option."""
    masked, vq = tmp_path / "net_best_fid.tar", tmp_path / "vq.tar"
    torch.save({"trans": release.states.masked, "ep": 3}, masked)
    torch.save({"net": release.states.vq, "ep": 3}, vq)
    models = load_momask(locate_release(release.root, {"masked": masked, "vq": vq, "length": None}))
    assert models.files.masked == masked and models.keys["masked"] == "trans" and models.keys["vq"] == "net"
    files = locate_release(None, {**release.files, "length": None})
    assert files.length is None and files.missing_length_note() == (
        "no --length file: the length estimator, needed for free length (a segment without a duration); imported "
        "without it, so every segment needs a duration")


def test_kit_folder_names_are_found(tmp_path):
    states = release_states(dataclasses.replace(SMALL, feat_dim=251, layers=1))
    write_release(tmp_path, states, suffix="_k")
    files = locate_release(tmp_path, {})
    assert files.dataset == "KIT-ML" and files.vq.parent.parent.name == "rvq_nq6_dc512_nc512_noshare_qdp0.2_k"
    assert files.length == tmp_path / "length_estimator" / "model" / "finest.tar"
    assert load_momask(files).vq.config.feat_dim == 251
    assert "plays 1.6 times too fast" in str(kit_fps_note(files.dataset)) and kit_fps_note("HumanML3D") is None


def _break(release: Release, target: Path, role: str, edit) -> Path:
    """A copy of the release with one file edited: edit(path, state) writes the broken file."""
    shutil.copytree(release.root, target)
    path = target / release.files[role].relative_to(release.root)
    edit(path)
    return target


def _save_masked(state: dict, key: str = "t2m_transformer"):
    return lambda path: torch.save({key: state, "ep": 1}, path)


def _masked_without(release: Release, key: str) -> dict:
    return {k: v for k, v in release.states.masked.items() if k != key}


def _masked_with(release: Release, key: str, value: torch.Tensor) -> dict:
    return {**release.states.masked, key: value}


@pytest.mark.parametrize("case", ["folder", "file", "meta", "key", "tensor", "shape", "truncated", "option"])
def test_refusals_are_one_line(case, release, clip_archive, tmp_path, capsys):
    root = tmp_path / "t2m"
    extra: list[str] = []
    if case == "folder":
        root, message = tmp_path / "nowhere", f"{tmp_path / 'nowhere'}: no such folder"
    elif case == "file":
        _break(release, root, "residual", Path.unlink)
        message = "tres_nlayer8_ld384_ff1024_rvq6ns_cdp0.2_sw/model/net_best_fid.tar: missing file: the residual"
    elif case == "meta":
        _break(release, root, "mean", Path.unlink)
        message = "meta/mean.npy: missing file: the VQ's meta mean (needed for de-normalisation)"
    elif case == "key":
        _break(release, root, "masked", _save_masked(release.states.masked, key="model"))
        message = "latest.tar: no key 't2m_transformer' or 'trans' (keys: model, ep)"
    elif case == "tensor":
        _break(release, root, "masked", _save_masked(_masked_without(release, "seqTransEncoder.layers.1.norm2.bias")))
        message = "latest.tar ['t2m_transformer']: missing tensor 'seqTransEncoder.layers.1.norm2.bias' [48]"
    elif case == "shape":
        _break(release, root, "masked", _save_masked(_masked_with(release, "seqTransEncoder.layers.1.linear2.weight",
                                                                  torch.zeros(48, 60))))
        message = "tensor 'seqTransEncoder.layers.1.linear2.weight' has shape [48, 60], expected [48, 64]"
    elif case == "truncated":
        _break(release, root, "vq", lambda path: path.write_bytes(path.read_bytes()[:5000]))
        message = "net_best_fid.tar: not a complete PyTorch file"
    else:
        root, extra = release.root, ["--length", str(tmp_path / "finest.tar")]
        message = f"{tmp_path / 'finest.tar'}: missing file: the length estimator"
    code = t2m(["import", "momask", str(root), "--clip", str(clip_archive), *extra, "-o", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.count("\n") == 0 and "Traceback" not in err, err
    assert message in err, err


def test_without_clip_the_import_says_what_it_needs(release, tmp_path, capsys):
    assert t2m(["import", "momask", str(release.root), "-o", str(tmp_path / "out")]) == 2
    assert "needs CLIP ViT-B/32 weights" in capsys.readouterr().err


@pytest.mark.slow
def test_full_release_sizes_match_the_reference(tmp_path, clip_archive, capsys):
    """The released sizes (19.4M VQ, 12.0M masked, 13.4M residual; random values) through the CLI: module and graph
    logits, token maps of the served bundle at top-k 1 and the decode vs the reference. Prints the measured figures
    (the model card's "Verified" line)."""
    release = make_release(tmp_path / "checkpoints" / "t2m", RELEASE)
    out = tmp_path / "bundle"
    assert t2m(["import", "momask", str(release.root), "--clip", str(clip_archive), "-o", str(out)]) == 0
    card = (out / "MODEL_CARD.md").read_text()
    assert "19,436,807" in card and "12,048,768" in card and "13,364,224" in card
    manifest = json.loads((out / "manifest.json").read_text())
    assert (manifest["masked"]["top_k"], manifest["masked"]["residual_top_k"]) == (52, 52)
    modules, graphs = check_module_logits(release), check_graph_logits(release, out)
    lengths = [49, 37, 1]
    served, conds = served_token_maps(out, lengths)
    expected = reference_token_maps(release, conds, lengths)
    for rows, got, want in zip(lengths, served, expected):
        np.testing.assert_array_equal(got, want, err_msg=f"length {rows}")
    decode, scales = check_decode(release, out, expected), logit_scales(release)
    with capsys.disabled():
        print(f"\nreleased sizes: max |logit| {scales}; max |diff| module logits {modules}, graph logits {graphs}, "
              f"decoded features {decode:.2e}")
    assert within(modules, scales) and within(graphs, scales) and decode <= 1e-4
