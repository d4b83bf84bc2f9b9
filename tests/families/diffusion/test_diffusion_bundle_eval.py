"""`t2m eval --bundle` of a diffusion bundle (MDM and DiP): the evaluation's motions are exactly the service's (one
sentence per request; a stream as one request, with the service's chained calls or in-betweened joins), and the
report has Table 1 and the stream table."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from t2m.cli.main import main
from t2m.export.evaluation import load_bundle_models
from t2m.families.diffusion.evaluation import TokenStateFeatures, split_token_states
from t2m.families.diffusion.random_bundle import build_random_diffusion_bundle
from t2m.model.evaluation.family import StreamFamily
from tests.model.synthetic_motion_data import make_dataset
from tests.model.test_evaluation import HashTextEncoder


@pytest.fixture(scope="module", params=["mdm", "dip"])
def diffusion_eval(request, tmp_path_factory):
    """A tiny random MDM or DiP bundle, a random tiny evaluator and the tiny dataset (test split = every clip)."""
    from t2m.model.networks.evaluator import EvaluatorConfig, MotionEvaluator
    from t2m.model.training.checkpoint import save_checkpoint

    root = tmp_path_factory.mktemp("diffusion_eval")
    build_random_diffusion_bundle(root / "bundle", arch=request.param, seed=3)
    data = make_dataset(root / "data", train_clips=6, val_clips=2)
    ids = [line for split in ("train", "val", "test") for line in (data / f"{split}.txt").read_text().split()]
    (data / "test.txt").write_text("\n".join(ids) + "\n")
    torch.manual_seed(0)
    save_checkpoint(root / "evaluator", MotionEvaluator(EvaluatorConfig(width=16, n_layer=1, n_head=2, embed_dim=8)), 0)
    return request.param, root / "bundle", root / "evaluator", data


def _served_features(bundle, texts, seconds, seed, guidance):
    """The engine's de-normalised features of one request (before the joints)."""
    from t2m.runtime.bundle_loader import load_bundle
    from t2m.runtime.engine import OnnxEngine
    from t2m.runtime.types import GenerationRequest, SegmentRequest

    engine = OnnxEngine.load(bundle, intra_op_threads=1)
    request = GenerationRequest(segments=[SegmentRequest(t, s) for t, s in zip(texts, seconds)], seed=seed,
                                guidance=guidance)
    job = engine.codes.job(request, engine.text, engine.limits)
    (parts,) = engine.codes.sample([job], engine.limits.max_tokens, None)
    loaded = load_bundle(bundle, intra_op_threads=1)
    return np.concatenate(parts) * loaded.std + loaded.mean


def test_token_states_round_trip_through_one_array(diffusion_eval):
    arch, bundle, evaluator, _ = diffusion_eval
    if arch != "dip":
        pytest.skip("pooled text: the features are the text graph's own")
    from t2m.runtime.text import encode_token_states

    models = load_bundle_models(evaluator, bundle)
    assert isinstance(models.family_text, TokenStateFeatures)
    texts = ["a person walks", "someone waves the right hand slowly"]
    packed = models.family_text.encode(texts)
    states, masks = encode_token_states(models.family_text.text, texts)
    for row, (state, mask) in enumerate(zip(states, masks)):
        got_state, got_mask = split_token_states(packed[row])
        np.testing.assert_array_equal(got_state, state)
        np.testing.assert_array_equal(got_mask, mask)


def test_diffusion_family_makes_the_services_motion(diffusion_eval):
    """A sentence of exactly its frames, and a stream of three sentences as one request, are the frames the service
    makes for the same texts, durations, guidance and seed."""
    _, bundle, evaluator, _ = diffusion_eval
    models = load_bundle_models(evaluator, bundle)
    assert models.family_text is not None and models.decoder is not None
    assert isinstance(models.family, StreamFamily)
    texts, seconds = ["a person walks forward", "someone waves", "a man jumps"], [1.0, 2.0, 0.6]
    frames = [round(s * 20) for s in seconds]
    cond = models.family_text.encode(texts)

    (single,) = models.family.codes(cond[:1], frames[:1], 2.0, 1.0, None, np.random.default_rng(7))
    assert len(single) == frames[0]
    np.testing.assert_allclose(models.decoder.decode_batch(single[None])[0],
                               _served_features(bundle, texts[:1], seconds[:1], 7, 2.0), rtol=0, atol=1e-5)

    (stream,) = models.family.sample_streams([cond], [frames], 2.0, np.random.default_rng(9))
    assert [len(part) for part in stream] == frames
    np.testing.assert_allclose(models.decoder.decode_batch(np.concatenate(stream)[None])[0],
                               _served_features(bundle, texts, seconds, 9, 2.0), rtol=0, atol=1e-5)
    # a control: another seed is another motion
    (other,) = models.family.sample_streams([cond], [frames], 2.0, np.random.default_rng(10))
    assert np.abs(np.concatenate(other) - np.concatenate(stream)).max() > 1e-2


def test_eval_diffusion_bundle_reports_table_1_and_streams(diffusion_eval, tmp_path, monkeypatch):
    monkeypatch.setattr("t2m.model.networks.text_encoders.get_text_encoder", lambda name, **kw: HashTextEncoder())
    torch.set_num_threads(1)
    _, bundle, evaluator, data = diffusion_eval
    out = tmp_path / "eval.md"
    assert main(["eval", "--bundle", str(bundle), "--data", str(data), "--evaluator", str(evaluator), "--repeats", "1",
                 "--mm-texts", "2", "--mm-repeats", "2", "--streams", "2", "--batch-size", "4", "--guidance", "2",
                 "--quiet", "--out", str(out)]) == 0
    report = out.read_text()
    assert "| Generation (guidance=2) |" in report and "| Streams (guidance=2) |" in report
    assert "diffusion:" in report   # the family's decoding line
    result = json.loads(out.with_suffix(".json").read_text())
    assert "recon" not in result["summary"]
    for key in ("fid", "top1", "mmodality"):
        assert math.isfinite(result["summary"]["gen_g2"][key][0]), key
    assert math.isfinite(result["summary"]["multi_g2"]["pelvis_jump_joins"][0])
