"""The opt-in model trained on Bandai-Namco and the CMU trials (t2m/bundles/both): a verified bundle that
shares the default's text files but has its own caption index, knows the CMU actions the default warns about, and
jumps when asked (the action probe written before it was trained; 0.80 on seeds 0-4 as measured, 0.00 for the
default). Its kick regression, the reason it is not the default, is pinned too."""
from __future__ import annotations

import pytest

from t2m.bundles import DEFAULT_BUNDLE, EMBEDDED_BUNDLES
from t2m.runtime.types import GenerationRequest, SegmentRequest

BOTH = EMBEDDED_BUNDLES["both"]
SEEDS = (0, 1, 2, 3, 4)


@pytest.fixture(scope="module")
def both_engine():
    from t2m.runtime.engine import OnnxEngine

    return OnnxEngine.load(BOTH, intra_op_threads=1)          # verifies every file's sha256


def test_the_bundle_shares_the_text_files_but_not_the_caption_index():
    for name in ("text_encoder.onnx", "tokenizer.json"):
        assert (BOTH / name).is_symlink() and (BOTH / name).resolve() == (DEFAULT_BUNDLE / name).resolve()
    assert not (BOTH / "caption_index.npz").is_symlink()
    assert (BOTH / "caption_index.npz").read_bytes() != (DEFAULT_BUNDLE / "caption_index.npz").read_bytes()


def test_it_knows_the_cmu_actions_the_default_warns_about(both_engine):
    from t2m.runtime.engine import OnnxEngine

    request = GenerationRequest(segments=[SegmentRequest("a person jumps up and down", 2.0),
                                          SegmentRequest("someone does a cartwheel", 2.0)], seed=0, guidance=3.0)
    assert both_engine.generate(request).warnings == []
    default_warnings = OnnxEngine.load(DEFAULT_BUNDLE, intra_op_threads=1).generate(request).warnings
    assert len(default_warnings) == 2, default_warnings


def _pass_rate(engine, name: str) -> float:
    from t2m.model.evaluation.action_probes import ACTION_PROBES
    from t2m.model.evaluation.probes import PROBES
    from t2m.quality.probes import run_probes

    [spec] = [spec for spec in (*PROBES, *ACTION_PROBES) if spec.name == name]
    report = run_probes(engine, SEEDS, engine.limits.guidance(), probes=[spec], stream=False, progress=False)
    return report.probe(name).pass_rate


def test_it_jumps_when_asked(both_engine):
    assert _pass_rate(both_engine, "jump") >= 0.6


@pytest.mark.xfail(strict=True, reason="the reason it is not the default: kick 0.37 (the default: 0.97); 'kicks a "
                   "ball hard' and 'kicks forward with one foot' 0/5 "
                   "(docs/measurements/cmu_actions_model_before_after.log)")
def test_it_kicks_like_the_default(both_engine):
    assert _pass_rate(both_engine, "kick") >= 0.6
