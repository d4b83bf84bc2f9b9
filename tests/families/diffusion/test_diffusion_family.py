"""The diffusion family's parts that need no server: the manifest block and its refusals, the graphs' signatures,
the CLI export, the sentence rules (DiP's segment chains, MDM's join windows) and the standing prefix. Every check
has a control that shows it can fail."""
from __future__ import annotations

import itertools
import json
import shutil

import numpy as np
import pytest
import torch

from t2m.bundle import BundleError, read_manifest
from t2m.families.diffusion.export import standing_prefix
from t2m.families.diffusion.loop import (
    SegmentChain,
    cosine_schedule,
    crossfade_weights,
    join_windows,
    sample_segment_chains,
)
from t2m.families.diffusion.random_bundle import build_random_diffusion_bundle, random_statistics
from t2m.motion.features import features_to_joints

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def bundles(tmp_path_factory):
    root = tmp_path_factory.mktemp("diffusion-family")
    return {arch: (root / arch, build_random_diffusion_bundle(root / arch, arch=arch)) for arch in ("mdm", "dip")}


def test_the_bundles_declare_the_family_block_and_graphs(bundles):
    import onnxruntime as ort

    mdm, dip = bundles["mdm"][1], bundles["dip"][1]
    assert mdm["diffusion"]["arch"] == "trans_enc" and mdm["diffusion"]["text_conditioning"] == "pooled"
    assert mdm["diffusion"]["pred_len"] == 0 and mdm["diffusion"]["prefix"] is None and "prefix.npy" not in mdm["files"]
    assert dip["diffusion"]["arch"] == "trans_dec" and dip["diffusion"]["text_conditioning"] == "tokens"
    assert dip["diffusion"]["prefix"] == "prefix.npy" and "prefix.npy" in dip["files"]
    assert (mdm["frames_per_token"], mdm["codebook_size"], mdm["residual_layers"]) == (1, 1, 1)

    def names(arch, graph, outputs=False):
        session = ort.InferenceSession(str(bundles[arch][0] / graph), providers=["CPUExecutionProvider"])
        return [x.name for x in (session.get_outputs() if outputs else session.get_inputs())]

    assert names("mdm", "denoiser.onnx") == ["x_t", "t", "text", "length"]
    assert names("dip", "denoiser.onnx") == ["x_t", "t", "text", "text_mask", "length", "prefix"]
    assert names("dip", "text_encoder.onnx", outputs=True) == ["token_states"]
    assert names("mdm", "text_encoder.onnx", outputs=True) == ["text_features"]
    assert names("mdm", "decoder.onnx") == ["motion"]


@pytest.mark.parametrize(("edit", "message"), [
    (lambda m: m.update(frames_per_token=4), "field 'frames_per_token' is 4, expected 1"),
    (lambda m: m["diffusion"].update(arch="trans_enc"), "'diffusion.text_conditioning' is 'tokens'"),
    (lambda m: m["diffusion"].update(pred_len=0), "'diffusion.context_len' (8) and 'diffusion.pred_len' (0)"),
    (lambda m: m["diffusion"].update(prefix=None), "field 'diffusion.prefix' must name"),
    (lambda m: m["diffusion"].update(steps=1), "field 'diffusion.steps' must be an integer >= 2"),
    (lambda m: m["diffusion"].update(text_conditioning="words"), "field 'diffusion.text_conditioning' must be"),
    (lambda m: m["diffusion"].pop("join_frames"), "missing field 'diffusion.join_frames'"),
    (lambda m: m["diffusion"].update(crossfade=-1), "field 'diffusion.crossfade' must be an integer >= 0"),
    (lambda m: m["diffusion"].update(crossfade=99), "'diffusion.crossfade' (99) must be at most"),
])
def test_a_bad_manifest_is_refused_naming_the_field(bundles, tmp_path, edit, message):
    copy = tmp_path / "bundle"
    shutil.copytree(bundles["dip"][0], copy)
    assert read_manifest(copy).family == "diffusion"   # control: the copy is valid as written
    manifest = json.loads((copy / "manifest.json").read_text())
    edit(manifest)
    (copy / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(BundleError) as error:
        read_manifest(copy)
    assert message in str(error.value)


def test_a_prefix_of_the_wrong_shape_is_refused_at_load(bundles, tmp_path):
    from t2m.export.writing.bundle import files_table
    from t2m.runtime.engine import OnnxEngine

    copy = tmp_path / "bundle"
    shutil.copytree(bundles["dip"][0], copy)
    np.save(copy / "prefix.npy", np.zeros((3, 263), np.float32))
    manifest = json.loads((copy / "manifest.json").read_text())
    manifest["files"].update(files_table(copy, {"prefix.npy": copy / "prefix.npy"}))
    (copy / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(BundleError, match=r"prefix.npy: shape \(3, 263\), expected"):
        OnnxEngine.load(copy, check_hashes=False, intra_op_threads=1)


def test_the_export_cli_writes_a_random_bundle_and_refuses_without_one(tmp_path, capsys):
    from t2m.cli.main import main

    assert main(["export", "--family", "diffusion", "--diffusion-random", "dip", "--diffusion-seed", "2",
                 "-o", str(tmp_path / "dip")]) == 0
    assert read_manifest(tmp_path / "dip").settings.chained
    capsys.readouterr()
    assert main(["export", "--family", "diffusion", "-o", str(tmp_path / "none")]) != 0
    assert "t2m import mdm|dip" in capsys.readouterr().err
    assert main(["export", "--family", "gpt", "--vq", "x", "--gpt", "y", "--diffusion-random", "mdm",
                 "-o", str(tmp_path / "z")]) == 2
    assert "--diffusion-random: only with --family diffusion" in capsys.readouterr().err
    assert main(["export", "--family", "diffusion", "--diffusion-random", "dip", "--int8", "text",
                 "-o", str(tmp_path / "q")]) != 0
    assert "--int8 text: quantises a trained run's text graph" in capsys.readouterr().err
    assert main(["export", "--family", "diffusion", "--diffusion-random", "dip", "--int8", "denoiser",
                 "-o", str(tmp_path / "q")]) != 0
    assert "--int8 denoiser: give none, all, or some of text" in capsys.readouterr().err
    assert main(["export", "--family", "diffusion", "--diffusion-random", "dip", "--crossfade", "10",
                 "-o", str(tmp_path / "q")]) != 0
    assert "--crossfade 10: for a trained DiP run" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------------ sentences


class Recorder:
    """A row-wise denoiser that records the prefixes and texts it is given."""

    def __init__(self) -> None:
        self.calls: list[tuple[np.ndarray, np.ndarray]] = []

    def __call__(self, x_t, t, text, text_mask, length, prefix):
        self.calls.append((prefix.copy(), text.copy()))
        return np.tanh(0.5 * x_t + text.mean(axis=1)[:, None, None] + prefix.mean(axis=1, keepdims=True))


def test_a_segment_covers_its_calls_and_the_next_continues_from_the_frames_kept():
    rng = np.random.default_rng(0)
    texts = [rng.standard_normal(4).astype(np.float32) for _ in range(3)]
    chain = SegmentChain(texts=texts, frames=[5, 9, 2], prefix=np.zeros((3, 2), np.float32),
                         rng=np.random.default_rng(1), guidance=1.0)
    assert chain.calls(4) == [(0, 4), (0, 1), (1, 4), (1, 4), (1, 1), (2, 2)]
    recorder = Recorder()
    (segments,) = sample_segment_chains(recorder, cosine_schedule(3), [chain], 4)
    assert [len(s) for s in segments] == [5, 9, 2]
    motion = np.concatenate(segments)
    firsts = recorder.calls[::3]   # each call's first step
    assert len(firsts) == 6
    # call 2 (segment 1's first) continues from the last 3 frames kept: segment 0's frames 2..4, not the dropped ones
    np.testing.assert_array_equal(firsts[2][0][0], motion[2:5])
    # each call's text is its segment's: calls 0-1 text 0, calls 2-4 text 1, call 5 text 2
    for call, segment in enumerate([0, 0, 1, 1, 1, 2]):
        np.testing.assert_array_equal(firsts[call][1][0], texts[segment])
    # control: a call after a 1-frame keep takes that frame and the two before it
    np.testing.assert_array_equal(firsts[5][0][0], motion[11:14])


class TextValueDenoiser:
    """A denoiser whose x0 is, on every frame, the mean of its row's text (0 for the null text), whatever x_t is; so
    a guided, cross-faded x0 is known in closed form, and at t = 0 the posterior mean is x0 itself."""

    def __call__(self, x_t, t, text, text_mask, length, prefix):
        value = (text * text_mask[..., None]).sum(axis=(1, 2)) / (text_mask.sum(axis=1) * text.shape[-1])
        return np.broadcast_to(value[:, None, None], x_t.shape).astype(np.float32)


def test_crossfade_weights_rise_from_zero_to_one_within_the_fade():
    np.testing.assert_allclose(crossfade_weights(6, 4)[:, 0], [0.0, 0.25, 0.5, 0.75, 1.0, 1.0])
    with pytest.raises(ValueError, match="at least one frame"):
        crossfade_weights(6, 0)


@pytest.mark.parametrize("fade", [0, 3])
def test_only_a_later_sentences_first_call_crossfades_from_the_previous_text(fade):
    """Texts of value 1 and 2, guidance 5: x0 = 0 + 5 (w 2 + (1 - w) 1 - 0) on each frame of the faded call, 5 x 2
    after it, 5 x 1 all through the first sentence; the batch carries one more row (the previous text) only then."""
    texts = [np.ones((2, 4), np.float32), 2 * np.ones((3, 4), np.float32)]
    rows: list[int] = []
    denoiser = TextValueDenoiser()

    def counting(*inputs):
        rows.append(len(inputs[0]))
        return denoiser(*inputs)

    chain = SegmentChain(texts=texts, frames=[4, 6], prefix=np.zeros((2, 3), np.float32),
                         rng=np.random.default_rng(0), guidance=5.0,
                         text_masks=[np.ones(2, bool), np.ones(3, bool)], crossfade=fade)
    (segments,) = sample_segment_chains(counting, cosine_schedule(2), [chain], 4)
    first, second = segments
    np.testing.assert_allclose(first, 5.0)
    weights = np.array([0, 1 / 3, 2 / 3, 1, 1, 1]) if fade else np.ones(6)   # calls of 4 + 2 kept frames
    np.testing.assert_allclose(second[:, 0], 5 * (2 * weights + (1 - weights)), rtol=1e-6)
    assert rows == [2, 2, 3 if fade else 2, 3 if fade else 2, 2, 2]   # 2 steps per call, 3 calls


def test_join_windows_stay_inside_their_segments_and_never_overlap():
    windows = join_windows([20, 30, 12], join=4, context=4)
    assert [(w.start, w.end, w.before, w.after) for w in windows] == [(12, 28, 4, 4), (42, 58, 4, 4)]
    short = join_windows([3, 2, 40], join=4, context=4)   # short sides make half of what they lend
    assert [(w.start, w.end, w.before, w.after) for w in short] == [(0, 4, 2, 1), (4, 13, 1, 4)]
    for frames in ([1, 1], [5, 1, 5], [60, 60, 60], [2, 7, 3, 9]):
        found = join_windows(frames, join=10, context=10)
        for first, second in itertools.pairwise(found):
            assert first.end <= second.start
        bounds = np.cumsum(frames)[:-1]
        for window in found:   # inside the motion, the frames made anew around its one join
            assert window.start >= 0 and window.end <= sum(frames)
            assert sum(window.start + window.before <= b <= window.end - window.after for b in bounds) == 1
    assert join_windows([20, 30], join=0, context=4) == []


def test_the_standing_prefix_decodes_to_a_pose_that_does_not_move():
    mean, std = random_statistics(3)
    prefix = standing_prefix(mean, std, 20)
    assert prefix.shape == (20, 263) and prefix.dtype == np.float32
    joints = features_to_joints(prefix * std + mean)
    assert np.abs(joints - joints[:1]).max() < 1e-6
    drifting = features_to_joints(np.zeros((20, 263), np.float32) * std + mean)   # control: the mean frame moves
    assert np.abs(drifting - drifting[:1]).max() > 1e-3


def test_the_exporter_refuses_a_crossfade_longer_than_a_call_before_writing_anything(tmp_path):
    """A DiP cross-fade happens within one call: the exporter refuses 17 frames on 16-frame calls before it writes
    any graph (the text source is never asked to write)."""
    from t2m.families.diffusion.export import export_diffusion_bundle
    from t2m.families.diffusion.random_bundle import random_diffusion_model

    class Untouched:
        def write(self, out_dir):
            raise AssertionError("the text graph was written before the cross-fade was checked")

    model = random_diffusion_model("dip", 0)
    assert model.config.pred_len == 16   # control: the refusal below is about the length, not the arch
    mean, std = random_statistics(0)
    with pytest.raises(ValueError, match=r"crossfade must be within 1\.\.16 \(one call\), got 17"):
        export_diffusion_bundle(tmp_path / "dip", model=model, mean=mean, std=std, text_source=Untouched(),
                                name="x", version="0.0.0", training_data={}, license="x", default_guidance=7.5,
                                crossfade=17)
    assert not any((tmp_path / "dip").glob("*.onnx"))
