"""The numpy loop (t2m.families.diffusion.loop) over a module (TorchDenoiser) vs the independent PyTorch reference of
the
official loop (t2m.families.diffusion.sampling), same injected noise, tiny random weights: MDM with guidance and
inpainting, DiP chains with a text per call; float-level agreement under batching of a mask_frames model."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from t2m.families.diffusion.loop import DiffusionChain, DiffusionJob, cosine_schedule, noise_from, sample, sample_chains
from t2m.families.diffusion.network import MDM, DiffusionConfig
from t2m.families.diffusion.sampling import TorchDenoiser, reference_chain, reference_sample, reference_tables

torch.set_num_threads(1)

F, DT = 7, 5
TOLERANCE = 1e-4


def tiny(steps: int = 10, **overrides) -> MDM:
    torch.manual_seed(0)
    settings = {"features": F, "latent_dim": 16, "layers": 2, "heads": 2, "ff_size": 32, "text_dim": DT,
                "diffusion_steps": steps, "pos_embed_max_len": 1024} | overrides
    return MDM(DiffusionConfig(**settings)).eval()


def draws(seed: int, count: int, frames: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.standard_normal((frames, F)).astype(np.float32) for _ in range(count)]


def as_torch(arrays: list[np.ndarray]):
    return iter(torch.from_numpy(a)[None] for a in arrays)


@pytest.mark.parametrize("steps", [10, 50])
def test_numpy_loop_matches_the_reference(steps):
    model = tiny(steps)
    noise = draws(1, steps + 1, 9)
    text = np.random.default_rng(2).standard_normal(DT).astype(np.float32)
    job = DiffusionJob(text=text, frames=9, rng=np.random.default_rng(0), guidance=2.5, noise=noise_from(noise))
    (ours,) = sample(TorchDenoiser(model), cosine_schedule(steps), [job], F)
    reference = reference_sample(model, torch.from_numpy(text)[None], 9, guidance=2.5, noise=as_torch(noise))[0]
    assert np.abs(ours - reference.numpy()).max() < TOLERANCE
    # control: another guidance scale in the reference is far outside the tolerance
    other = reference_sample(model, torch.from_numpy(text)[None], 9, guidance=2.0, noise=as_torch(noise))[0]
    assert np.abs(ours - other.numpy()).max() > 100 * TOLERANCE


def test_reference_tables_agree_with_the_numpy_schedule():
    for steps in (10, 50, 1000):
        ours, theirs = cosine_schedule(steps), reference_tables(steps)
        np.testing.assert_allclose(theirs["coef1"].numpy(), ours.coef1, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(theirs["coef2"].numpy(), ours.coef2, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(theirs["log_variance"].numpy(), ours.posterior_log_variance, rtol=1e-12)


def test_inpainting_matches_the_reference_and_keeps_known_values():
    model = tiny()
    noise = draws(3, 11, 12)
    text = np.random.default_rng(4).standard_normal(DT).astype(np.float32)
    known = np.random.default_rng(5).standard_normal((12, F)).astype(np.float32)
    mask = np.ones((12, F), bool)
    mask[3:9] = False
    job = DiffusionJob(text=text, frames=12, rng=np.random.default_rng(0), guidance=2.5, known=known,
                       known_mask=mask, noise=noise_from(noise))
    (ours,) = sample(TorchDenoiser(model), cosine_schedule(10), [job], F)
    reference = reference_sample(model, torch.from_numpy(text)[None], 12, guidance=2.5, noise=as_torch(noise),
                                 known=torch.from_numpy(known)[None], known_mask=torch.from_numpy(mask)[None])[0]
    assert np.abs(ours - reference.numpy()).max() < TOLERANCE
    assert np.array_equal(ours[mask], known[mask]) and torch.equal(reference[torch.from_numpy(mask)],
                                                                   torch.from_numpy(known[mask]))


@pytest.mark.parametrize("emb_trans_dec", [False, True])
def test_dip_chain_matches_the_reference(emb_trans_dec):
    """Three calls (20 frames, 8 per call after a 4-frame prefix), a text per call with its own token count."""
    model = tiny(arch="trans_dec", text_tokens=True, mask_frames=True, context_len=4, pred_len=8,
                 emb_trans_dec=emb_trans_dec)
    rng = np.random.default_rng(6)
    texts = [rng.standard_normal((n, DT)).astype(np.float32) for n in (3, 5, 2)]
    masks = [np.array([True, True, False]), np.ones(5, bool), np.ones(2, bool)]
    prefix = rng.standard_normal((4, F)).astype(np.float32)
    noise = draws(7, 3 * 11, 8)
    chain = DiffusionChain(texts=texts, prefix=prefix, frames=20, rng=np.random.default_rng(0), guidance=7.5,
                           text_masks=masks, noise=noise_from(noise))
    (ours,) = sample_chains(TorchDenoiser(model), cosine_schedule(10), [chain], pred_len=8)
    reference = reference_chain(model, [torch.from_numpy(t)[None] for t in texts], torch.from_numpy(prefix)[None],
                                20, guidance=7.5, text_masks=[torch.from_numpy(m)[None] for m in masks],
                                noise=as_torch(noise))[0]
    assert ours.shape == (20, F)
    assert np.abs(ours - reference.numpy()).max() < TOLERANCE
    # control: the reference with the texts' order changed is another motion
    swapped = reference_chain(model, [torch.from_numpy(t)[None] for t in texts[::-1]],
                              torch.from_numpy(prefix)[None], 20, guidance=7.5,
                              text_masks=[torch.from_numpy(m)[None] for m in masks[::-1]], noise=as_torch(noise))[0]
    assert np.abs(ours - swapped.numpy()).max() > 100 * TOLERANCE


def test_batched_requests_match_alone_at_float_level():
    """A mask_frames model: requests of different lengths and guidance in one batch give what they give alone."""
    model = tiny(arch="trans_dec", text_tokens=True, mask_frames=True)

    def jobs() -> list[DiffusionJob]:
        rng = np.random.default_rng(8)
        return [DiffusionJob(text=rng.standard_normal((n, DT)).astype(np.float32), frames=frames,
                             rng=np.random.default_rng(seed), guidance=guidance, text_mask=np.ones(n, bool))
                for n, frames, seed, guidance in ((3, 6, 1, 2.5), (4, 11, 2, 1.0), (2, 9, 3, 7.5))]

    together = sample(TorchDenoiser(model), cosine_schedule(10), jobs(), F)
    alone = [sample(TorchDenoiser(model), cosine_schedule(10), [one], F)[0] for one in jobs()]
    for mine, theirs in zip(together, alone):
        assert np.abs(mine - theirs).max() < 1e-5
    # control: a 2022-style model (no mask_frames) lets the longer rows' padding leak into the short one
    leaky = tiny(arch="trans_dec", text_tokens=True, mask_frames=False)
    together = sample(TorchDenoiser(leaky), cosine_schedule(10), jobs(), F)
    alone_first = sample(TorchDenoiser(leaky), cosine_schedule(10), jobs()[:1], F)[0]
    assert np.abs(together[0] - alone_first).max() > 1e-3
