"""T2M-HiFiGPT's decoding loop (t2m.families.hifigpt.loop) with scripted numpy steps: guidance on the stop logits (the
paper's formula), the stop and target rules, guided codes fed to both rows, draws that do not depend on the batch,
cancellation."""
from __future__ import annotations

import numpy as np
import pytest

from t2m.decoding.lockstep import SamplingJob
from t2m.decoding.tokens import draw_stops, stop_probability
from t2m.families.hifigpt.loop import sample_code_rows

K, R, E, DT = 6, 3, 4, 5


class ScriptedTemporal:
    """Stop logit `cond_stop` for a text row, `null_stop` for a null row; the context carries the row's text and the
    sum of the codes it was fed (so the residual logits depend on the history). Records the codes it is fed."""

    depth = R

    def __init__(self, cond_stop: float = -9.0, null_stop: float = -9.0) -> None:
        self.cond_stop, self.null_stop = cond_stop, null_stop
        self.fed: list[np.ndarray] = []

    def empty_cache(self, batch: int) -> np.ndarray:
        return np.zeros((1, 2, batch, 1, 0, 1), np.float32)

    def __call__(self, cond, codes, position, length, past):
        self.fed.append(codes.copy())
        null = ~cond.any(axis=1)
        context = np.zeros((len(cond), E), np.float32)
        context[:, 0] = cond.argmax(axis=1)
        context[:, 1] = codes.sum(axis=1) + position
        context[:, 2] = null
        stop = np.where(null, self.null_stop, self.cond_stop).astype(np.float32)
        grown = np.concatenate([past, np.zeros((1, 2, len(cond), 1, 1, 1), np.float32)], axis=4)
        return context, stop, grown


class ScriptedResidual:
    """Logits favouring code (text + history + depth + previous code) % K for a text row, code 0 for a null row."""

    def empty_cache(self, batch: int) -> np.ndarray:
        return np.zeros((1, 2, batch, 1, 0, 1), np.float32)

    def __call__(self, context, code, depth, past):
        favourite = (context[:, 0] + context[:, 1] + depth + code).astype(np.int64) % K
        favourite[context[:, 2] > 0] = 0
        logits = np.zeros((len(context), K), np.float32)
        logits[np.arange(len(context)), favourite] = 3.0
        grown = np.concatenate([past, np.zeros((1, 2, len(context), 1, 1, 1), np.float32)], axis=4)
        return logits, grown


def _job(texts: list[int], targets: list[int | None], seed: int = 0, **settings) -> SamplingJob:
    conds = np.eye(DT, dtype=np.float32)[texts]
    defaults = {"guidance": 1.0, "temperature": 1.0, "top_k": None}
    return SamplingJob(conds=conds, targets=targets, rng=np.random.default_rng(seed), **{**defaults, **settings})


def test_stop_probability_is_the_tempered_sigmoid():
    np.testing.assert_allclose(stop_probability(np.array([0.0, np.log(3.0), -np.log(3.0)])), [0.5, 0.75, 0.25])
    np.testing.assert_allclose(stop_probability(np.array([2.0]), temperature=2.0), [1 / (1 + np.exp(-1.0))])
    assert stop_probability(np.array([-800.0, 800.0])).tolist() == [0.0, 1.0]      # no overflow
    stops = draw_stops(np.full(20000, np.log(3.0)), 1.0, np.random.default_rng(0))
    assert 0.74 < stops.mean() < 0.76
    assert draw_stops(np.array([0.1, -0.1]), 1.0, np.random.default_rng(0), greedy=True).tolist() == [True, False]


@pytest.mark.parametrize("guidance, steps", [(1.0, 1), (0.7, 1), (0.6, 6), (3.0, 1)])
def test_guidance_applies_the_papers_formula_to_the_stop_logits(guidance, steps):
    """cond stop logit 2, null -4: guided = -4 + s (2 - -4) is 2 at s=1, 0.2 at s=0.7 (stop after the first step,
    greedy), -0.4 at s=0.6 (never: the segment runs to max_tokens), 14 at s=3."""
    temporal = ScriptedTemporal(cond_stop=2.0, null_stop=-4.0)
    (maps,) = sample_code_rows(temporal, ScriptedResidual(), [_job([1], [None], guidance=guidance, greedy=True)],
                               max_tokens=6)
    assert maps is not None and maps[0].shape == (steps, R)


def test_targets_end_exactly_and_a_free_segment_takes_at_least_one_step():
    temporal = ScriptedTemporal(cond_stop=50.0, null_stop=50.0)   # the stop head wants to stop at once
    (maps,) = sample_code_rows(temporal, ScriptedResidual(), [_job([0, 1, 2], [3, None, 5], guidance=2.0)],
                               max_tokens=8)
    assert maps is not None and [m.shape for m in maps] == [(3, R), (1, R), (5, R)]
    never = ScriptedTemporal(cond_stop=-50.0, null_stop=-50.0)
    (maps,) = sample_code_rows(never, ScriptedResidual(), [_job([1], [None])], max_tokens=4)
    assert maps is not None and maps[0].shape == (4, R)
    with pytest.raises(ValueError, match=r"outside 1\.\.8"):
        sample_code_rows(never, ScriptedResidual(), [_job([1], [9])], max_tokens=8)


def test_codes_follow_the_guided_logits_and_feed_both_rows():
    temporal = ScriptedTemporal()
    (maps,) = sample_code_rows(temporal, ScriptedResidual(), [_job([2], [3], guidance=3.0, greedy=True)],
                               max_tokens=8)
    assert maps is not None
    history, previous = 0, 0
    for step, row in enumerate(maps[0]):   # the text row's favourite, as guidance 3 sharpens it against code 0
        for depth, code in enumerate(row):
            previous = (2 + history + step + depth + (previous if depth else 0)) % K
            assert code == previous
        history = int(row.sum())
    fed = temporal.fed[1]
    assert fed.shape == (2, R) and np.array_equal(fed[0], fed[1]) and np.array_equal(fed[0], maps[0][0])


def test_a_requests_codes_do_not_depend_on_its_batch():
    alone = sample_code_rows(ScriptedTemporal(0.0, -1.0), ScriptedResidual(),
                             [_job([1, 3], [None, 4], seed=7, guidance=2.0)], max_tokens=8)[0]
    jobs = [_job([0], [6], seed=1), _job([1, 3], [None, 4], seed=7, guidance=2.0), _job([4, 4], [None, 2], seed=3,
                                                                                      guidance=1.5, top_k=2)]
    batched = sample_code_rows(ScriptedTemporal(0.0, -1.0), ScriptedResidual(), jobs, max_tokens=8)[1]
    assert alone is not None and batched is not None
    assert all(np.array_equal(a, b) for a, b in zip(alone, batched))


def test_a_cancelled_job_stops_and_the_others_finish():
    calls = {"n": 0}

    def cancelled() -> bool:
        calls["n"] += 1
        return calls["n"] > 2

    doomed = SamplingJob(conds=np.eye(DT, dtype=np.float32)[[1]], targets=[6], guidance=1.0, temperature=1.0,
                         top_k=None, rng=np.random.default_rng(0), cancelled=cancelled)
    result = sample_code_rows(ScriptedTemporal(), ScriptedResidual(), [doomed, _job([2], [6])], max_tokens=8)
    assert result[0] is None and result[1] is not None and result[1][0].shape == (6, R)


def test_progress_sees_each_positions_code_rows_and_the_finished_segments():
    """What streaming reads: after every position, each segment's rows so far and whether it is finished; the last
    call holds the returned maps (a free segment's stop leaves its rows as they were)."""
    seen: list[tuple[list[int], list[bool]]] = []
    last: list[list[np.ndarray]] = []

    def progress(segments, done) -> None:
        seen.append(([len(rows) for rows in segments], list(done)))
        last[:] = [[np.array(row) for row in rows] for rows in segments]

    job = _job([1, 2], [2, None], seed=3, guidance=2.0)
    job.progress = progress
    (maps,) = sample_code_rows(ScriptedTemporal(cond_stop=50.0, null_stop=50.0), ScriptedResidual(), [job],
                               max_tokens=6)
    assert maps is not None and [m.shape for m in maps] == [(2, R), (1, R)]
    # position 0: a row each; 1: the target reached and the free segment stopped
    assert seen == [([1, 1], [False, False]), ([2, 1], [True, True])]
    assert all(np.array_equal(np.stack(rows), m) for rows, m in zip(last, maps))
