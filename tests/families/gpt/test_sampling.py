"""The PyTorch reference sampler (t2m.families.gpt.sampling over t2m.families.gpt.loop): the End rule, greedy parity
with the
full forward, top-k, seeds."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from t2m.decoding.tokens import guided_logits, sample_tokens
from t2m.families.gpt.network import GPTConfig, MotionGPT
from t2m.families.gpt.sampling import sample_codes

torch.set_num_threads(1)
K = 12
MAX_TOKENS = 8


def tiny_gpt(length_conditioning: bool = True, seed: int = 0) -> MotionGPT:
    torch.manual_seed(seed)
    config = GPTConfig(codebook_size=K, embed=32, n_head=4, n_layer_base=1, n_layer_head=1,
                       block_size=MAX_TOKENS + 1, text_dim=8, dropout=0.0, length_conditioning=length_conditioning)
    return MotionGPT(config).eval()


def constant_logits_gpt(logits: torch.Tensor) -> MotionGPT:
    """A GPT whose output is `logits` at every step: ln_f maps everything to e_0, head column 0 holds the logits."""
    gpt = tiny_gpt()
    with torch.no_grad():
        gpt.trans_head.ln_f.weight.zero_()
        gpt.trans_head.ln_f.bias.zero_()
        gpt.trans_head.ln_f.bias[0] = 1.0
        gpt.trans_head.head.weight.zero_()
        gpt.trans_head.head.weight[:, 0] = logits
    return gpt


def test_guidance_formula():
    rng = np.random.default_rng(0)
    cond, uncond = rng.normal(size=(4, 13)), rng.normal(size=(4, 13))
    np.testing.assert_allclose(guided_logits(cond, uncond, 3.0), uncond + 3.0 * (cond - uncond))
    np.testing.assert_allclose(guided_logits(cond, uncond, 1.0), cond)
    np.testing.assert_allclose(guided_logits(cond, uncond, 0.0), uncond)


def test_end_is_masked_before_the_target_and_forced_at_it():
    favourite_end = torch.zeros(K + 1)
    favourite_end[K] = 10.0  # End would always win
    gpt = constant_logits_gpt(favourite_end)
    cond = torch.randn(3, 8)
    codes = sample_codes(gpt, cond, [3, 1, None], guidance=1.0, greedy=True)
    assert [len(c) for c in codes] == [3, 1, 1]  # free length: at least one code, then End
    assert all(0 <= code < K for row in codes for code in row)

    never_end = torch.zeros(K + 1)
    never_end[K] = -10.0
    never_end[4] = 5.0
    gpt = constant_logits_gpt(never_end)
    codes = sample_codes(gpt, cond, [5, MAX_TOKENS, None], guidance=2.0, temperature=0.7, top_k=3,
                         rng=0)
    assert [len(c) for c in codes] == [5, MAX_TOKENS, MAX_TOKENS]  # End forced at the target / at max_tokens


def manual_greedy(gpt: MotionGPT, cond: torch.Tensor, target: int, guidance: float) -> list[int]:
    """Greedy decoding with the full (uncached) forward and explicit guidance, one row at a time."""
    tokens = torch.zeros(1, 0, dtype=torch.long)
    length = torch.tensor([target])
    codes = []
    for _ in range(target):
        c = gpt(cond[None], tokens, length)[:, -1]
        u = gpt(torch.zeros_like(cond[None]), tokens, length)[:, -1]
        logits = u + guidance * (c - u)
        logits[:, K] = float("-inf")
        code = int(logits.argmax())
        codes.append(code)
        tokens = torch.cat([tokens, torch.tensor([[code]])], dim=1)
    return codes


@pytest.mark.parametrize("guidance", [1.0, 2.5])
def test_greedy_sampling_matches_a_manual_uncached_loop(guidance):
    gpt = tiny_gpt()
    cond = torch.randn(2, 8)
    targets = [4, 6]
    codes = sample_codes(gpt, cond, targets, guidance=guidance, temperature=0.0)
    for row, target in enumerate(targets):
        assert codes[row] == manual_greedy(gpt, cond[row], target, guidance)


def test_top_k_one_is_greedy_and_seeds_repeat():
    gpt = tiny_gpt()
    cond = torch.randn(2, 8)
    greedy = sample_codes(gpt, cond, [5, None], guidance=3.0, greedy=True)
    top1 = sample_codes(gpt, cond, [5, None], guidance=3.0, top_k=1, rng=1)
    assert greedy == top1
    first = sample_codes(gpt, cond, [6, 6], temperature=1.5, rng=7)
    again = sample_codes(gpt, cond, [6, 6], temperature=1.5, rng=7)
    assert first == again


def test_sample_tokens_keeps_top_k_and_draws_once_per_row():
    logits = np.array([[1.0, 5.0, 3.0, 4.0, -9.0]] * 2000)
    drawn = sample_tokens(logits, np.ones(2000, bool), end_id=4, temperature=2.0, top_k=2,
                          rng=np.random.default_rng(0))
    assert set(drawn.tolist()) == {1, 3}                           # only the two largest classes
    share = (drawn == 1).mean()                                    # softmax([5, 4] / 2): 0.622 for class 1
    assert abs(share - 1 / (1 + np.exp(-0.5))) < 0.03
    rng = np.random.default_rng(5)
    sample_tokens(logits[:7], np.ones(7, bool), 4, 1.0, None, rng)
    assert rng.bit_generator.state == _advanced(5, 7)              # 7 rows -> exactly 7 uniforms drawn
    greedy = sample_tokens(logits[:3], np.zeros(3, bool), 4, 1.0, None, np.random.default_rng(0), greedy=True)
    assert greedy.tolist() == [1, 1, 1]


def _advanced(seed: int, draws: int) -> dict:
    rng = np.random.default_rng(seed)
    rng.random(draws)
    return rng.bit_generator.state


def test_bad_targets_raise():
    gpt = tiny_gpt()
    with pytest.raises(ValueError, match=r"segment 1: target of .* tokens is outside"):
        sample_codes(gpt, torch.randn(2, 8), [3, MAX_TOKENS + 1])
    with pytest.raises(ValueError, match="1 targets for 2 condition rows"):
        sample_codes(gpt, torch.randn(2, 8), [3])
