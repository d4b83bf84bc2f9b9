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
