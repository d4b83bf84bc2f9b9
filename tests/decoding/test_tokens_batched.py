"""One batched draw for many requests (tokens.draw_tokens_of_jobs, lockstep.draw_for_jobs) gives exactly the
numbers of one draw per request, whatever options each request has and whatever shares its step."""
from __future__ import annotations

import numpy as np
import pytest

from t2m.decoding.lockstep import Rows, SamplingJob, draw_for_jobs, guided
from t2m.decoding.tokens import RowRule, draw_tokens, draw_tokens_of_jobs, sample_tokens

OPTIONS = [{"temperature": 1.0, "top_k": None, "greedy": False}, {"temperature": 0.7, "top_k": 5, "greedy": False},
           {"temperature": 1.3, "top_k": None, "greedy": True}, {"temperature": 1.0, "top_k": 40, "greedy": False},
           {"temperature": 0.9, "top_k": 5, "greedy": False}]


@pytest.mark.parametrize("seed", range(5))
def test_a_batched_draw_is_the_draws_one_by_one(seed):
    rng = np.random.default_rng(seed)
    counts = [1, 3, 2, 1, 2]
    logits = rng.standard_normal((sum(counts), 64)) * 3
    rules = [RowRule(n, o["temperature"], o["top_k"], np.random.default_rng(100 + i), o["greedy"])
             for i, (n, o) in enumerate(zip(counts, OPTIONS))]
    batched = draw_tokens_of_jobs(logits, rules)
    start, alone = 0, []
    for i, (n, o) in enumerate(zip(counts, OPTIONS)):
        alone.append(draw_tokens(logits[start:start + n], o["temperature"], o["top_k"],
                                 np.random.default_rng(100 + i), o["greedy"]))
        start += n
    assert np.array_equal(batched, np.concatenate(alone))
    # control: the draws do depend on each request's generator (other seeds change some choice)
    reseeded = [RowRule(r.rows, r.temperature, r.top_k, np.random.default_rng(500 + i), r.greedy)
                for i, r in enumerate(rules)]
    assert not np.array_equal(draw_tokens_of_jobs(logits, reseeded), batched)


@pytest.mark.parametrize("seed", range(5))
def test_guided_jobs_drawn_together_match_each_job_alone(seed):
    rng = np.random.default_rng(seed)
    guidance = [1.0, 3.0, 2.5]
    segments = {0: [0, 1], 1: [2], 2: [3, 4]}                  # job -> its active segments
    cond_rows = {s: s for s in range(5)}
    null_rows = {2: 5, 3: 6, 4: 7}                              # guided jobs' segments have null rows
    logits = rng.standard_normal((8, 32)).astype(np.float32)
    rows = Rows(cond_rows, null_rows)

    def jobs() -> list[SamplingJob]:
        return [SamplingJob.of(np.zeros((len(segments[j]), 4), np.float32), [5] * len(segments[j]), max_tokens=9,
                               guidance=g, temperature=0.8, top_k=10, rng=50 + j) for j, g in enumerate(guidance)]

    together = draw_for_jobs(logits, rows, [(job, segments[j]) for j, job in enumerate(jobs())])
    for j, job in enumerate(jobs()):
        alone = draw_tokens(guided(job, segments[j], logits, rows), job.temperature, job.top_k, job.rng)
        assert np.array_equal(together[j], alone), j
    # the End rule as the GPT applies it (sample_tokens), for the same rows
    mask = np.array([True, False, True, False, True])
    together = draw_for_jobs(logits, rows, [(job, segments[j]) for j, job in enumerate(jobs())], forbid=(mask, 31))
    start = 0
    for j, job in enumerate(jobs()):
        n = len(segments[j])
        alone = sample_tokens(guided(job, segments[j], logits, rows), mask[start:start + n], 31, job.temperature,
                              job.top_k, job.rng)
        assert np.array_equal(together[j], alone), j
        start += n


def test_many_jobs_drawn_in_groups_give_one_draws_numbers(monkeypatch):
    """Above DRAW_GROUP segments the draw goes in runs of whole jobs (to stay in the CPU's cache): the same codes
    as one draw over all of them, End rule included, for jobs of 1-3 segments with and without guidance."""
    import t2m.decoding.lockstep as lockstep

    rng = np.random.default_rng(7)
    sizes = rng.integers(1, 4, size=120).tolist()
    owner = np.repeat(np.arange(sum(sizes)), 2)          # a cond and a null row per segment
    rows = lockstep.row_maps(owner)
    logits = (rng.standard_normal((len(owner), 33)) * 3).astype(np.float32)
    mask = rng.random(sum(sizes)) < 0.5

    def draw(group: int) -> list[list[int]]:
        monkeypatch.setattr(lockstep, "DRAW_GROUP", group)
        starts = np.cumsum([0, *sizes[:-1]]).tolist()
        going = [(SamplingJob.of(np.zeros((n, 4), np.float32), [5] * n, max_tokens=9, guidance=(1.0, 3.0)[j % 2],
                                 temperature=0.9, top_k=(None, 8)[j % 3 == 0], rng=j), list(range(s, s + n)))
                 for j, (n, s) in enumerate(zip(sizes, starts))]
        return [codes.tolist() for codes in draw_for_jobs(logits, rows, going, forbid=(mask, 32))]

    one = draw(10_000)
    assert draw(16) == one and draw(5) == one
    assert draw(1) == one                                  # every job its own draw


def test_a_plan_of_several_draws_gives_the_draws_one_by_one():
    """T2M-HiFiGPT's depth draws: one DrawPlan for R draws, each job's R uniforms taken from its generator at once,
    gives the codes of R separate draw_for_jobs calls (greedy and sampling jobs, more segments than DRAW_GROUP)."""
    import t2m.decoding.lockstep as lockstep

    rng = np.random.default_rng(3)
    sizes = rng.integers(1, 4, size=40).tolist()
    starts = np.cumsum([0, *sizes[:-1]]).tolist()
    owner = np.repeat(np.arange(sum(sizes)), 2)
    rows = lockstep.row_maps(owner)
    logits = [(rng.standard_normal((len(owner), 17)) * 2).astype(np.float32) for _ in range(4)]

    def going() -> list:
        return [(SamplingJob.of(np.zeros((n, 4), np.float32), [5] * n, max_tokens=9, guidance=(1.0, 2.5)[j % 2],
                                temperature=(1.0, 0.8)[j % 3 == 1], top_k=(None, 6)[j % 4 == 0], greedy=j % 5 == 0,
                                rng=j), list(range(s, s + n)))
                for j, (n, s) in enumerate(zip(sizes, starts))]

    one_by_one = [np.concatenate(draw_for_jobs(step_logits, rows, jobs)).tolist()
                  for jobs in [going()] for step_logits in logits]
    plan = lockstep.DrawPlan(rows, going(), draws=4)
    assert [plan.draw(step_logits).tolist() for step_logits in logits] == one_by_one
    with pytest.raises(RuntimeError, match="made for 4 draw"):
        plan.draw(logits[0])


def _full_width_draw(logits: np.ndarray, temperature: float, top_k: int | None, uniforms: np.ndarray) -> np.ndarray:
    """draw_tokens as it was written before the top-k shortcut: exp and cumsum over every class."""
    logits = np.array(logits, dtype=np.float64) / temperature
    if top_k is not None and top_k < logits.shape[1]:
        kth_largest = np.partition(logits, -top_k, axis=1)[:, -top_k, None]
        logits[logits < kth_largest] = -np.inf
    logits -= logits.max(axis=1, keepdims=True)
    cdf = np.cumsum(np.exp(logits), axis=1)
    choice = (cdf <= (uniforms * cdf[:, -1])[:, None]).sum(axis=1)
    return np.minimum(choice, logits.shape[1] - 1)


class _Handing:
    """A stand-in generator that hands out fixed uniforms, all at once."""

    def __init__(self, uniforms: np.ndarray) -> None:
        self.uniforms = uniforms

    def random(self, n: int) -> np.ndarray:
        assert n == len(self.uniforms)
        return self.uniforms


@pytest.mark.parametrize("seed", range(6))
def test_the_top_k_shortcut_picks_what_the_full_width_draw_picks(seed):
    """With a top-k filter the exp and cumsum run over the kept classes only (tokens._pick): the same choices as over
    every class, for spread-out logits, for logits with ties at the k-th (the full-width path), for logits so far
    apart that kept classes underflow to 0, and for uniforms at the very top of [0, 1)."""
    rng = np.random.default_rng(seed)
    cases = [rng.standard_normal((40, 513)) * 3,                          # no ties: the shortcut
             np.round(rng.standard_normal((40, 513))),                   # ties at the k-th: full width
             rng.standard_normal((40, 513)) * 400]                       # kept classes that underflow
    for logits in cases:
        for top_k, temperature in [(52, 1.0), (1, 1.0), (5, 0.7), (512, 1.3)]:
            uniforms = rng.random(len(logits))
            uniforms[:3] = [0.0, 1 - 2**-53, 0.5]
            want = _full_width_draw(logits, temperature, top_k, uniforms)

            got = draw_tokens(logits, temperature, top_k, _Handing(uniforms))  # type: ignore[arg-type]
            assert np.array_equal(got, want), (top_k, temperature)
            rules = [RowRule(len(logits), temperature, top_k, _Handing(uniforms))]  # type: ignore[arg-type]
            assert np.array_equal(draw_tokens_of_jobs(logits, rules), want)
