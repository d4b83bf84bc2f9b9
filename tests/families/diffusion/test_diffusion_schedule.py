"""The cosine schedule of MDM/DiP (t2m.families.diffusion.loop): closed forms, the numbers the facts doc states
(../shared/docs/diffusion-models.md §3.1), the posterior identities, and the float32 cast per step."""
from __future__ import annotations

import math

import numpy as np
import pytest

from t2m.families.diffusion.loop import cosine_alpha_bar, cosine_betas, cosine_schedule

STEPS = (10, 50, 1000)


@pytest.mark.parametrize("steps", STEPS)
def test_alpha_bar_follows_the_closed_form_until_the_clipped_last_step(steps):
    schedule = cosine_schedule(steps)
    closed = np.array([cosine_alpha_bar((i + 1) / steps) / cosine_alpha_bar(0.0) for i in range(steps)])
    np.testing.assert_allclose(schedule.alphas_cumprod[:-1], closed[:-1], rtol=1e-10)
    # the last beta is clipped to 0.999, so the last alpha-bar is the one before times 0.001
    assert schedule.alphas_cumprod[-1] == pytest.approx(schedule.alphas_cumprod[-2] * 0.001, rel=1e-10)
    assert schedule.betas.dtype == np.float64 and schedule.steps == steps


def test_the_numbers_the_facts_doc_states():
    ten = cosine_schedule(10)
    assert ten.betas[0] == pytest.approx(0.0279, abs=5e-5)
    assert ten.betas[-2] == pytest.approx(0.744, abs=5e-4)
    assert ten.alphas_cumprod[-1] == pytest.approx(2.41e-5, abs=5e-8)
    assert cosine_schedule(50).betas[0] == pytest.approx(1.75e-3, abs=5e-6)
    assert cosine_schedule(1000).betas[0] == pytest.approx(4.13e-5, abs=5e-8)
    for steps in STEPS:
        assert cosine_schedule(steps).betas[-1] == pytest.approx(0.999, abs=1e-12)


@pytest.mark.parametrize("steps", STEPS)
def test_betas_are_rederived_from_the_cumulative_product(steps):
    """The respacing wrapper's betas, 1 - ᾱ_i/ᾱ_{i-1}: equal to the raw cosine betas up to float64 rounding."""
    raw, used = cosine_betas(steps), cosine_schedule(steps).betas
    np.testing.assert_allclose(used, raw, rtol=0, atol=1e-15)
    alpha_bar = np.cumprod(1.0 - raw)
    expected = 1.0 - alpha_bar / np.append(1.0, alpha_bar[:-1])
    assert np.array_equal(used, expected)


def test_control_rederived_betas_are_not_the_raw_ones_bit_for_bit():
    """Control: the re-derivation matters in the last bits (for 1000 steps), so the equality above is a real check."""
    assert (cosine_schedule(1000).betas != cosine_betas(1000)).any()


@pytest.mark.parametrize("steps", STEPS)
def test_posterior_tables(steps):
    s = cosine_schedule(steps)
    alphas = 1.0 - s.betas
    np.testing.assert_allclose(s.alphas_cumprod_prev, np.append(1.0, s.alphas_cumprod[:-1]), rtol=0, atol=0)
    np.testing.assert_allclose(s.posterior_variance,
                               s.betas * (1 - s.alphas_cumprod_prev) / (1 - s.alphas_cumprod), rtol=1e-12)
    # x_t = sqrt(ᾱ_t) x0 without noise must step to sqrt(ᾱ_{t-1}) x0
    np.testing.assert_allclose(s.coef1 + s.coef2 * np.sqrt(s.alphas_cumprod), np.sqrt(s.alphas_cumprod_prev),
                               rtol=1e-12)
    np.testing.assert_allclose(s.coef2, (1 - s.alphas_cumprod_prev) * np.sqrt(alphas) / (1 - s.alphas_cumprod),
                               rtol=1e-12)
    # FIXED_SMALL: the log-variance's entry 0 (log 0) is replaced by entry 1
    assert s.posterior_variance[0] == 0.0
    assert s.posterior_log_variance[0] == s.posterior_log_variance[1] == math.log(s.posterior_variance[1])


@pytest.mark.parametrize("steps", STEPS)
def test_last_step_keeps_the_prediction_exactly(steps):
    """At t = 0 the float32 coefficients are exactly 1 and 0: why known values come out exactly."""
    coef1, coef2, sigma = cosine_schedule(steps).at(0)
    assert coef1 == np.float32(1.0) and coef2 == np.float32(0.0)
    assert coef1.dtype == coef2.dtype == sigma.dtype == np.float32


def test_per_step_values_are_float32_casts_of_the_float64_tables():
    s = cosine_schedule(50)
    coef1, coef2, sigma = s.at(17)
    assert coef1 == np.float32(s.coef1[17]) and coef2 == np.float32(s.coef2[17])
    assert sigma == pytest.approx(math.sqrt(s.posterior_variance[17]), rel=1e-6)


def test_control_float32_tables_differ():
    """Control: tables built in float32 are not the float64 ones (the doc: a 1.2e-5 effect on a 50-step run)."""
    betas32 = cosine_betas(50).astype(np.float32)
    alpha_bar32 = np.cumprod(np.float32(1) - betas32, dtype=np.float32)
    assert np.abs(alpha_bar32 - cosine_schedule(50).alphas_cumprod).max() > 1e-9


def test_too_few_steps_refused():
    with pytest.raises(ValueError):
        cosine_schedule(1)
    with pytest.raises(ValueError):
        cosine_betas(0)
