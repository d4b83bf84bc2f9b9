"""`t2m eval --bundle`: the evaluation of a served GPT or T2M-HiFiGPT bundle makes exactly the service's motions (same
codes, same decoder, same joints for a seed), and the report has no VQ-reconstruction row (a bundle has no VQ
encoder)."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from t2m.cli.main import main
from t2m.export.evaluation import load_bundle_models
from t2m.families.gpt.random_bundle import build_random_bundle
from t2m.families.hifigpt.random_bundle import build_random_hifigpt_bundle
from t2m.motion.features import features_to_joints
from tests.model.synthetic_motion_data import make_dataset
from tests.model.test_evaluation import HashTextEncoder


@pytest.fixture(scope="module", params=["gpt", "hifigpt"])
def bundle_and_evaluator(request, tmp_path_factory):
    """A tiny random GPT or T2M-HiFiGPT bundle, a random tiny evaluator and the tiny dataset (test split = every
    clip)."""
    from t2m.model.networks.evaluator import EvaluatorConfig, MotionEvaluator
    from t2m.model.training.checkpoint import save_checkpoint

    root = tmp_path_factory.mktemp("bundle_eval")
    if request.param == "gpt":
        bundle = build_random_bundle(root / "bundle", codebook_size=16, embed=16, n_head=2, n_layer=2)
    else:
        torch.set_num_threads(1)
        bundle = build_random_hifigpt_bundle(root / "bundle", depth=3, codebook_size=16, seed=2)
    data = make_dataset(root / "data", train_clips=6, val_clips=2)
    ids = [line for split in ("train", "val", "test") for line in (data / f"{split}.txt").read_text().split()]
    (data / "test.txt").write_text("\n".join(ids) + "\n")
    torch.manual_seed(0)
    save_checkpoint(root / "evaluator", MotionEvaluator(EvaluatorConfig(width=16, n_layer=1, n_head=2, embed_dim=8)), 0)
    return bundle, root / "evaluator", data


def test_bundle_family_makes_the_services_motion(bundle_and_evaluator):
    """Codes from the family (one job, rows in order, the request's generator) decoded by its decoder give the
    joints the engine serves for the same sentences, durations and seed."""
    from t2m.runtime.engine import OnnxEngine
    from t2m.runtime.types import GenerationRequest, SegmentRequest

    bundle, evaluator, _ = bundle_and_evaluator
    models = load_bundle_models(evaluator, bundle)
    texts, seconds = ["a person walks forward", "someone waves", "a man jumps"], [1.0, 2.0, 0.6]
    request = GenerationRequest(segments=[SegmentRequest(t, s) for t, s in zip(texts, seconds)], seed=7,
                                guidance=3.0, temperature=1.0, top_k=8)
    # the decoded motion, before the service fits each segment to its exact frame count (engine/timeline.py)
    served = OnnxEngine.load(bundle, intra_op_threads=1, exact_durations=False).generate(request)
    assert models.family_text is not None and models.decoder is not None
    per_step = json.loads((bundle / "manifest.json").read_text())["frames_per_token"]
    tokens = [round(s * 20 / per_step) for s in seconds]
    codes = models.family.codes(models.family_text.encode(texts), tokens, 3.0, 1.0, 8, np.random.default_rng(7))
    assert [len(c) for c in codes] == tokens
    features = models.decoder.decode_batch(np.concatenate(codes)[None])[0]
    np.testing.assert_array_equal(np.asarray(features_to_joints(features), np.float32), served.joints)


def test_eval_bundle_reports_table_1_without_reconstruction(bundle_and_evaluator, tmp_path, monkeypatch):
    monkeypatch.setattr("t2m.model.networks.text_encoders.get_text_encoder", lambda name, **kw: HashTextEncoder())
    torch.set_num_threads(1)
    bundle, evaluator, data = bundle_and_evaluator
    out = tmp_path / "eval.md"
    assert main(["eval", "--bundle", str(bundle), "--data", str(data), "--evaluator", str(evaluator), "--repeats", "1",
                 "--mm-texts", "2", "--mm-repeats", "2", "--streams", "2", "--batch-size", "4", "--quiet",
                 "--out", str(out)]) == 0
    report = out.read_text()
    assert "| Generation (guidance=3) |" in report and "| Streams (guidance=1) |" in report
    assert "VQ reconstruction |" not in report and "VQ codes, decoded once" not in report
    assert "No VQ reconstruction row" in report
    result = json.loads(out.with_suffix(".json").read_text())
    assert result["models"]["bundle"] == str(bundle) and "recon" not in result["summary"]
    assert math.isfinite(result["summary"]["gen_g3"]["fid"][0])


def test_eval_bundle_refuses_runs_beside_it(bundle_and_evaluator, capsys):
    bundle, evaluator, data = bundle_and_evaluator
    code = main(["eval", "--bundle", str(bundle), "--vq", "runs/vq", "--data", str(data), "--evaluator",
                 str(evaluator)])
    assert code == 2 and "--bundle replaces --vq" in capsys.readouterr().err
