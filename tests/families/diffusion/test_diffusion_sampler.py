"""The diffusion loop (t2m.families.diffusion.loop) over scripted numpy denoisers: the step formula, guidance rows,
noise order and injection, inpainting (known values come out exactly), DiP chaining, determinism under batching.
Every check has a control that shows it can fail."""
from __future__ import annotations

import numpy as np
import pytest

from t2m.families.diffusion.loop import (
    DiffusionChain,
    DiffusionJob,
    chain_calls,
    cosine_schedule,
    denoise_step,
    guided,
    noise_from,
    official_to_frames,
    sample,
    sample_chains,
    start,
)

F, DT = 6, 4


class Scripted:
    """A row-wise x0 predictor (each row's output depends only on that row) that records what it is given."""

    def __init__(self, leak: float = 0.0) -> None:
        self.calls: list[dict] = []
        self.leak = leak          # > 0: rows see the batch's mean (a batch-dependent denoiser, for controls)

    def __call__(self, x_t, t, text, text_mask, length, prefix):
        self.calls.append({"x": x_t.copy(), "t": t.copy(), "text": text.copy(), "length": length.copy(),
                           "mask": None if text_mask is None else text_mask.copy(),
                           "prefix": None if prefix is None else prefix.copy()})
        if text_mask is not None:
            summary = (text * text_mask[..., None]).sum(axis=(1, 2))
        else:
            summary = text.sum(axis=1)
        ramp = np.sin(np.arange(x_t.shape[1] * F).reshape(1, x_t.shape[1], F))     # per frame, not per batch
        out = np.tanh(0.5 * x_t + summary[:, None, None] * ramp + 0.01 * t[:, None, None])
        if prefix is not None:
            out = out + prefix.mean(axis=(1, 2))[:, None, None]
        if self.leak:
            out = out + self.leak * x_t.mean(axis=0, keepdims=True)
        return out.astype(np.float32)


def text(seed: int, tokens: int | None = None) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.standard_normal((tokens, DT) if tokens else DT).astype(np.float32)


def job(seed: int = 1, frames: int = 5, text_seed: int | None = None, **settings) -> DiffusionJob:
    """A job whose text comes from `text_seed` (default: from its seed)."""
    return DiffusionJob(text=text(100 + (seed if text_seed is None else text_seed)), frames=frames,
                        rng=np.random.default_rng(seed), **settings)


def run(jobs, steps=10, denoiser=None):
    return sample(denoiser or Scripted(), cosine_schedule(steps), jobs, F)


def test_guidance_formula():
    cond, uncond = np.array([1.0, 2.0], np.float32), np.array([0.5, -1.0], np.float32)
    np.testing.assert_array_equal(guided(cond, uncond, 2.5), np.float32([1.75, 6.5]))
    assert np.array_equal(guided(cond, uncond, 1.0), cond)
    assert np.array_equal(guided(cond, uncond, 0.0), uncond)          # edit.py's empty text: the null pass exactly
    assert guided(cond, uncond, 2.5).dtype == np.float32


def test_one_step_by_hand():
    """x_{N-1} = coef1 x0 + coef2 x_T + sigma z with x0 = uncond + s (cond - uncond) of one batched call."""
    schedule, denoiser = cosine_schedule(10), Scripted()
    draws = [np.random.default_rng(k).standard_normal((5, F)).astype(np.float32) for k in range(2)]
    one = job(guidance=2.5, noise=noise_from(draws))
    start(one, schedule, F)
    denoise_step(denoiser, schedule, [one])
    (call,) = denoiser.calls
    assert call["x"].shape == (2, 5, F) and list(call["t"]) == [9, 9]
    assert np.array_equal(call["text"][0], one.text) and not call["text"][1].any()      # cond row, zero-text row
    again = Scripted()(call["x"], call["t"], call["text"], None, call["length"], None)
    x0 = again[1] + np.float32(2.5) * (again[0] - again[1])
    coef1, coef2, sigma = schedule.at(9)
    np.testing.assert_allclose(one.x, coef1 * x0 + coef2 * draws[0] + sigma * draws[1], rtol=0, atol=1e-6)
    assert one.t == 8


def test_guidance_rows_are_batched_only_for_guided_jobs():
    denoiser = Scripted()
    masks = [np.array([True, True, False]), np.array([True, True])]
    jobs = [DiffusionJob(text=text(1, 3), frames=4, rng=np.random.default_rng(1), guidance=7.5, text_mask=masks[0]),
            DiffusionJob(text=text(2, 2), frames=6, rng=np.random.default_rng(2), guidance=1.0, text_mask=masks[1])]
    run(jobs, denoiser=denoiser)
    assert len(denoiser.calls) == 10
    call = denoiser.calls[0]
    assert call["x"].shape == (3, 6, F) and list(call["length"]) == [4, 6, 4]
    np.testing.assert_array_equal(call["mask"], [[1, 1, 0], [1, 1, 0], [1, 1, 0]])     # null row keeps its mask
    assert not call["text"][2].any() and call["text"][0].any()
    assert not call["x"][0, 4:].any()                                                # padded past its length


def test_noise_order_is_x_T_then_one_draw_per_step_including_t0():
    """Injecting the generator's own draws (x_T, then N) gives the generator's result: the draw order."""
    steps = 10
    draws_rng = np.random.default_rng(7)
    draws = [draws_rng.standard_normal((5, F), dtype=np.float32) for _ in range(steps + 1)]
    (drawn,) = run([job(seed=7, guidance=2.5)], steps)
    (injected,) = run([job(seed=99, text_seed=7, guidance=2.5, noise=noise_from(draws))], steps)
    assert np.array_equal(drawn, injected)
    with pytest.raises(ValueError, match="ran out"):
        run([job(guidance=2.5, noise=noise_from(draws[:-1]))], steps)
    with pytest.raises(ValueError, match="shape"):
        run([job(frames=4, noise=noise_from(draws))], steps)
    # control: the same draws in another order give another motion
    (swapped,) = run([job(text_seed=7, guidance=2.5, noise=noise_from([draws[1], draws[0], *draws[2:]]))], steps)
    assert np.abs(swapped - drawn).max() > 1e-3


def test_official_layout_conversion():
    official = np.arange(2 * F * 3, dtype=np.float32).reshape(2, F, 1, 3)
    frames = official_to_frames(official)
    assert frames.shape == (2, 3, F) and frames[1, 2, 4] == official[1, 4, 0, 2]


@pytest.mark.parametrize("steps", [10, 50, 1000])
def test_inpainting_known_values_come_out_exactly(steps):
    rng = np.random.default_rng(3)
    known = rng.standard_normal((12, F)).astype(np.float32)
    in_between = np.ones((12, F), bool)
    in_between[3:9] = False                                   # keep [0, 3) and [9, 12): in-between
    body = np.zeros((1, F), bool)
    body[0, :2] = True                                        # a few feature dims kept on every frame: body parts
    for mask in (in_between, body):
        (out,) = run([job(frames=12, guidance=2.5, known=known, known_mask=mask)], steps)
        kept = np.broadcast_to(mask, known.shape)
        assert np.array_equal(out[kept], known[kept])
        assert np.abs(out[~kept] - known[~kept]).max() > 1e-2            # the rest is generated
    # control: without the mask the known values do not come out
    (free,) = run([job(frames=12, guidance=2.5)], steps)
    assert np.abs(free[in_between] - known[in_between]).max() > 1e-2


def test_inpainting_needs_values_and_mask_of_the_motions_shape():
    with pytest.raises(ValueError):
        run([job(known=np.zeros((5, F), np.float32))])
    with pytest.raises(ValueError):
        run([job(known=np.zeros((4, F), np.float32), known_mask=np.ones((4, F), bool))])
    with pytest.raises(ValueError):
        run([job(known=np.zeros((5, F), np.float32), known_mask=np.ones((5, 1, F), bool))])


def test_same_seed_same_motion():
    assert np.array_equal(run([job(seed=4, guidance=2.5)])[0], run([job(seed=4, guidance=2.5)])[0])
    other_seed = run([job(seed=5, text_seed=4, guidance=2.5)])[0]
    assert np.abs(run([job(seed=4, guidance=2.5)])[0] - other_seed).max() > 1e-3


def batch_of_three() -> list[DiffusionJob]:
    known = np.full((7, F), 0.25, np.float32)
    mask = np.zeros((7, F), bool)
    mask[:2] = True
    return [job(seed=1, frames=5, guidance=2.5), job(seed=2, frames=9, guidance=1.0),
            job(seed=3, frames=7, guidance=0.0, known=known, known_mask=mask)]


def test_batching_gives_each_request_its_result_alone():
    together = run(batch_of_three())
    alone = [run([one])[0] for one in batch_of_three()]
    for mine, theirs in zip(together, alone):
        assert np.array_equal(mine, theirs)


def test_control_batching_test_sees_a_batch_dependent_denoiser():
    together = run(batch_of_three(), denoiser=Scripted(leak=0.5))
    alone = run(batch_of_three()[:1], denoiser=Scripted(leak=0.5))
    assert np.abs(together[0] - alone[0]).max() > 1e-3


def test_jobs_at_different_steps_share_a_call():
    """Continuous batching: a job started later is stepped beside one half-way through; each at its own t."""
    schedule, denoiser = cosine_schedule(10), Scripted()
    first, second = job(seed=1, guidance=2.5), job(seed=2, guidance=2.5)
    start(first, schedule, F)
    for _ in range(4):
        denoise_step(denoiser, schedule, [first])
    start(second, schedule, F)
    denoise_step(denoiser, schedule, [first, second])
    assert list(denoiser.calls[-1]["t"]) == [5, 9, 5, 9]
    while first.t >= 0 or second.t >= 0:
        denoise_step(denoiser, schedule, [first, second])
    assert np.array_equal(first.x, run([job(seed=1, guidance=2.5)])[0])
    assert np.array_equal(second.x, run([job(seed=2, guidance=2.5)])[0])


def chain(seed: int, frames: int, texts: int = 1, context: int = 4) -> DiffusionChain:
    prefix = np.random.default_rng(seed + 50).standard_normal((context, F)).astype(np.float32)
    return DiffusionChain(texts=[text(seed * 10 + k, 3) for k in range(texts)], prefix=prefix, frames=frames,
                          rng=np.random.default_rng(seed), guidance=7.5,
                          text_masks=[np.array([True, True, k % 2 == 0]) for k in range(texts)])


def test_chain_call_count():
    assert (chain_calls(80, 40), chain_calls(100, 40), chain_calls(120, 40), chain_calls(1, 40)) == (2, 3, 3, 1)


def test_chaining_prefix_is_the_previous_calls_last_frames():
    denoiser, one = Scripted(), chain(1, frames=20, texts=3)
    initial = one.prefix.copy()
    (out,) = sample_chains(denoiser, cosine_schedule(10), [one], pred_len=8)
    assert out.shape == (20, F)
    calls = [denoiser.calls[i * 10] for i in range(3)]                       # the first step of each call
    assert len(denoiser.calls) == 30
    assert np.array_equal(calls[0]["prefix"][0], initial)
    assert np.array_equal(calls[1]["prefix"][0], out[4:8])                   # frames 4..7 of call 0's 8
    assert np.array_equal(calls[2]["prefix"][0], out[12:16])
    assert calls[1]["x"].shape == (2, 8, F)                                  # 8 new frames, cond + null rows
    # control: the prefix is not the first frames of the previous call
    assert not np.array_equal(calls[1]["prefix"][0], out[0:4])


def test_chaining_text_changes_per_call_and_the_last_text_repeats():
    denoiser, one = Scripted(), chain(2, frames=32, texts=2)
    sample_chains(denoiser, cosine_schedule(10), [one], pred_len=8)
    texts = [denoiser.calls[i * 10]["text"][0] for i in range(4)]
    masks = [denoiser.calls[i * 10]["mask"][0] for i in range(4)]
    assert np.array_equal(texts[0], one.texts[0]) and np.array_equal(texts[1], one.texts[1])
    assert np.array_equal(texts[2], one.texts[1]) and np.array_equal(texts[3], one.texts[1])
    assert list(masks[0]) == [True, True, True] and list(masks[1]) == [True, True, False]


def test_chain_continues_from_its_updated_prefix():
    """Two calls of 8 frames made as one chain equal a chain of one call continued by another."""
    whole = sample_chains(Scripted(), cosine_schedule(10), [chain(3, frames=16)], pred_len=8)[0]
    part = chain(3, frames=8)
    first = sample_chains(Scripted(), cosine_schedule(10), [part], pred_len=8)[0]
    assert np.array_equal(part.prefix, first[-4:])
    part.frames = 8
    second = sample_chains(Scripted(), cosine_schedule(10), [part], pred_len=8)[0]
    assert np.array_equal(np.concatenate([first, second]), whole)


def test_chains_batched_give_each_its_result_alone():
    together = sample_chains(Scripted(), cosine_schedule(10), [chain(1, 20, 3), chain(2, 9, 2)], pred_len=8)
    alone = [sample_chains(Scripted(), cosine_schedule(10), [c], pred_len=8)[0] for c in (chain(1, 20, 3),
                                                                                          chain(2, 9, 2))]
    assert together[1].shape == (9, F)
    for mine, theirs in zip(together, alone):
        assert np.array_equal(mine, theirs)
