"""The GPT step loop: length rules, guidance, top-k, cancellation, batch invariance and parity with PyTorch."""
from __future__ import annotations

import numpy as np
import pytest

from t2m.decoding.tokens import sample_tokens
from t2m.families.gpt.loop import SamplingJob, sample_codes

V = 8          # codebook size of the scripted step
END = V


class ScriptedStep:
    """A stand-in GPT step: logits chosen per row from its condition; checks the KV-cache shapes it is fed."""

    n_layer, n_head, head_dim = 1, 1, 2

    def __init__(self, end_after: int | None = None) -> None:
        self.end_after = end_after      # logits favour End from this position on
        self.calls: list[int] = []

    def empty_cache(self, batch: int) -> np.ndarray:
        return np.zeros((1, 2, batch, 1, 0, 2), dtype=np.float32)

    def __call__(self, cond, token, position, length, past):
        batch = len(cond)
        assert past.shape == (1, 2, batch, 1, position, 2), (past.shape, position)
        assert token.shape == (batch,) and length.shape == (batch,)
        self.calls.append(batch)
        logits = np.zeros((batch, V + 1), dtype=np.float32)
        preferred = np.argmax(cond, axis=1)                 # a one-hot condition names the favourite code
        logits[np.arange(batch), preferred] = 5.0
        null_rows = ~cond.any(axis=1)
        logits[null_rows] = 0.0
        logits[null_rows, 2] = 5.0                           # the null condition favours code 2
        if self.end_after is not None and position >= self.end_after:
            logits[:, END] = 50.0
        present = np.concatenate([past, np.zeros((1, 2, batch, 1, 1, 2), dtype=np.float32)], axis=4)
        return logits, present


def _cond(*codes: int) -> np.ndarray:
    cond = np.zeros((len(codes), V), dtype=np.float32)
    cond[np.arange(len(codes)), codes] = 1.0
    return cond


def _job(cond, targets, guidance=1.0, top_k=1, seed=0, temperature=1.0, cancelled=lambda: False):
    return SamplingJob(conds=cond, targets=targets, guidance=guidance, temperature=temperature, top_k=top_k,
                       rng=np.random.default_rng(seed), cancelled=cancelled)


def test_fixed_targets_give_exactly_that_many_codes_and_never_end():
    step = ScriptedStep(end_after=0)                         # End is by far the likeliest everywhere
    (codes,) = sample_codes(step, [_job(_cond(3, 5), [4, 2], top_k=None)], max_tokens=10, end_id=END)
    assert [len(c) for c in codes] == [4, 2]
    assert all((c < V).all() for c in codes)
    assert step.calls == [2, 2, 1, 1]                        # the finished row leaves the batch


def test_free_segments_stop_on_end_but_never_first():
    (codes,) = sample_codes(ScriptedStep(end_after=0), [_job(_cond(3), [None])], max_tokens=10, end_id=END)
    assert codes[0].tolist() == [3]                          # End masked at the first token, taken at the second
    (codes,) = sample_codes(ScriptedStep(end_after=4), [_job(_cond(3), [None])], max_tokens=10, end_id=END)
    assert codes[0].tolist() == [3, 3, 3, 3]
    (codes,) = sample_codes(ScriptedStep(), [_job(_cond(3), [None])], max_tokens=6, end_id=END)
    assert len(codes[0]) == 6                                # never End: stops at max_tokens


@pytest.mark.parametrize("guidance, expected", [(1.0, 3), (0.0, 2), (3.0, 3)])
def test_guidance_combines_cond_and_null_rows(guidance, expected):
    step = ScriptedStep()
    (codes,) = sample_codes(step, [_job(_cond(3), [3], guidance=guidance)], max_tokens=10, end_id=END)
    assert codes[0].tolist() == [expected] * 3
    assert step.calls[0] == (1 if guidance == 1.0 else 2)    # a null row only when guidance != 1


def test_sample_tokens_top_k_temperature_and_end_mask():
    rng = np.random.default_rng(0)
    logits = np.array([[0.0, 1.0, 3.0, 2.0, 9.0]])
    assert sample_tokens(logits, np.array([True]), 4, 1.0, 1, rng).tolist() == [2]     # End masked -> next best
    assert sample_tokens(logits, np.array([False]), 4, 1.0, 1, rng).tolist() == [4]
    draws = [sample_tokens(logits, np.array([True]), 4, 1.0, 2, rng)[0] for _ in range(200)]
    assert set(draws) == {2, 3}                                                         # top-2 of the codes
    flat = [sample_tokens(logits, np.array([True]), 4, 100.0, None, rng)[0] for _ in range(400)]
    assert set(flat) == {0, 1, 2, 3}                                                    # hot: all codes appear
    cold = [sample_tokens(logits, np.array([True]), 4, 0.05, None, rng)[0] for _ in range(50)]
    assert set(cold) == {2}


def test_same_seed_same_codes_and_batch_invariance():
    step = ScriptedStep()
    cond = np.random.default_rng(1).normal(size=(2, V)).astype(np.float32)
    alone = sample_codes(step, [_job(cond, [5, None], top_k=None, seed=7)], 12, END)[0]
    again = sample_codes(step, [_job(cond, [5, None], top_k=None, seed=7)], 12, END)[0]
    other = _job(_cond(1, 2, 3), [9, 9, 2], guidance=2.0, top_k=None, seed=99)
    together = sample_codes(step, [other, _job(cond, [5, None], top_k=None, seed=7)], 12, END)[1]
    for a, b, c in zip(alone, again, together):
        assert a.tolist() == b.tolist() == c.tolist()
    different = sample_codes(step, [_job(cond, [5, None], top_k=None, seed=8)], 12, END)[0]
    assert any(a.tolist() != d.tolist() for a, d in zip(alone, different))


def test_cancelled_job_stops_and_others_finish():
    calls = {"n": 0}

    def cancelled() -> bool:
        calls["n"] += 1
        return calls["n"] > 2

    results = sample_codes(ScriptedStep(), [_job(_cond(1), [8], cancelled=cancelled), _job(_cond(4), [8])], 10, END)
    assert results[0] is None
    assert results[1][0].tolist() == [4] * 8


def test_target_beyond_max_tokens_is_refused():
    with pytest.raises(ValueError, match=r"outside 1\.\.10"):
        sample_codes(ScriptedStep(), [_job(_cond(1), [11])], 10, END)


# ------------------------------------------------------------------- parity with the PyTorch reference sampler

@pytest.fixture(scope="module")
def torch_bundle(tmp_path_factory):
    """A tiny GPT (End logits amplified so free segments end at varied lengths) exported next to its module."""
    import torch

    from t2m.export.kit.text_sources import tiny_text_source
    from t2m.families.gpt.export import export_bundle
    from t2m.families.gpt.network import GPTConfig, MotionGPT
    from t2m.model.networks.vqvae import MotionVQVAE, VQConfig

    torch.set_num_threads(1)
    torch.manual_seed(3)
    vq = MotionVQVAE(VQConfig(width=16, code_dim=8, nb_code=16, depth=1))
    gpt = MotionGPT(GPTConfig(codebook_size=16, embed=32, n_head=2, n_layer_base=1, n_layer_head=1, block_size=21,
                              text_dim=16, length_conditioning=True)).eval()
    with torch.no_grad():
        gpt.trans_head.head.weight[16] *= 6.0
    out = tmp_path_factory.mktemp("parity") / "bundle"
    export_bundle(out, vq=vq, gpt=gpt, mean=np.zeros(263, np.float32), std=np.ones(263, np.float32),
                  text_source=tiny_text_source(16, 16), name="parity", version="0", unconditional_branch=True,
                  default_guidance=2.0, training_data={"name": "none", "license": "-", "attribution": "-"},
                  license="-")
    return out, gpt


@pytest.mark.parametrize("guidance", [1.0, 2.5])
def test_greedy_codes_match_pytorch_reference(torch_bundle, guidance):
    import torch

    from t2m.families.gpt.sampling import sample_codes as torch_sample_codes
    from t2m.runtime.engine import OnnxEngine

    path, gpt = torch_bundle
    engine = OnnxEngine.load(path, intra_op_threads=1)
    texts = ["a person walks forward", "someone waves", "a man jumps", "turn left", "sit down slowly"]
    targets = [3, None, 7, None, 20]
    cond = engine.text.encode(texts)
    expected = torch_sample_codes(gpt, torch.from_numpy(cond), targets, guidance=guidance, greedy=True)
    job = _job(cond, targets, guidance=guidance, top_k=1)
    (ours,) = sample_codes(engine.codes.step, [job], engine.limits.max_tokens, engine.bundle.manifest.settings.end_id)
    assert [c.tolist() for c in ours] == expected
    lengths = [len(c) for c in expected]
    assert lengths[0] == 3 and lengths[2] == 7 and lengths[4] == 20
    assert len(set(lengths)) > 2                              # the free segments ended on their own


@pytest.mark.parametrize(("guidance", "temperature", "top_k"), [(1.0, 1.0, None), (2.5, 0.8, 5)])
def test_seeded_sampling_matches_pytorch_reference(torch_bundle, guidance, temperature, top_k):
    """Not only greedy: with the same seed, the service (onnxruntime) and the PyTorch reference draw the same codes,
    because both run one loop (t2m.families.gpt.loop) and their logits agree to ~1e-6."""
    from t2m.families.gpt.sampling import sample_codes as torch_sample_codes
    from t2m.runtime.engine import OnnxEngine

    path, gpt = torch_bundle
    engine = OnnxEngine.load(path, intra_op_threads=1)
    texts = ["a person walks forward", "someone waves", "a man jumps", "turn left", "sit down slowly"]
    targets = [3, None, 7, None, 20]
    cond = engine.text.encode(texts)
    for seed in range(4):
        expected = torch_sample_codes(gpt, cond, targets, guidance=guidance, temperature=temperature, top_k=top_k,
                                      rng=seed)
        job = _job(cond, targets, guidance=guidance, temperature=temperature, top_k=top_k, seed=seed)
        (ours,) = sample_codes(engine.codes.step, [job], engine.limits.max_tokens,
                               engine.bundle.manifest.settings.end_id)
        assert [c.tolist() for c in ours] == expected, seed
        other_seed = torch_sample_codes(gpt, cond, targets, guidance=guidance, temperature=temperature,
                                        top_k=top_k, rng=seed + 100)
        assert other_seed != expected                            # the draws do depend on the seed
