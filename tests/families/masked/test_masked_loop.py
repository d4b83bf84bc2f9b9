"""The masked family's decoding loop (t2m.families.masked.loop): re-masking counts per step, freezing, guidance per
stage, seeds that do not depend on the batch, residual layers, and the same tokens through modules and graphs."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from t2m.families.masked.loop import MaskedJob, remask_counts, sample_branch_maps, sample_token_maps

K, MASK, COLUMNS = 8, 8, 2


class ScriptedMasked:
    """Logits that favour code (row + column) % K for a one-hot condition, code 5 for the null row; records the
    number of masked tokens it is shown per call."""

    columns, mask_id = COLUMNS, MASK

    def __init__(self) -> None:
        self.masked_seen: list[list[int]] = []

    def __call__(self, tokens, cond, length):
        batch, rows, columns = tokens.shape
        self.masked_seen.append([int((tokens[b, : length[b]] == MASK).sum()) for b in range(batch)])
        logits = np.zeros((batch, rows, columns, K), np.float32)
        for b in range(batch):
            favourite = (np.arange(rows)[:, None] + np.arange(columns)[None, :] + int(cond[b].argmax())) % K
            if not cond[b].any():
                favourite[:] = 5
            np.put_along_axis(logits[b], favourite[..., None], 4.0, axis=-1)
        return logits


class ScriptedResidual:
    layers, pad_id, mask_id = 3, K, None

    def __init__(self) -> None:
        self.layers_seen: list[int] = []

    def __call__(self, codes, layer, cond, length):
        self.layers_seen.append(int(layer[0]))
        batch, rows, columns, _ = codes.shape
        logits = np.zeros((batch, rows, columns, K + 1), np.float32)
        logits[..., int(layer[0])] = 6.0           # layer q favours code q
        logits[..., K] = 7.0 if int(layer[0]) == 2 else -9.0   # layer 2: "unused" (pad) is the likeliest
        return logits


def _job(conds, rows, seed=0, **settings) -> MaskedJob:
    return MaskedJob(conds=np.asarray(conds, np.float32), rows=rows, rng=np.random.default_rng(seed), **settings)


def test_remask_counts_are_momasks():
    assert remask_counts(49, 10) == [49, 48, 46, 42, 38, 31, 24, 17, 9, 1]
    assert remask_counts(49 * 6, 10) == [294, 290, 276, 255, 225, 189, 147, 101, 51, 1]
    assert remask_counts(5, 1) == [5]
    with pytest.raises(ValueError, match="steps and tokens must be >= 1"):
        remask_counts(0, 3)


def test_each_step_masks_the_scheduled_count_and_fills_the_map():
    masked = ScriptedMasked()
    conds = np.eye(4)[:2]
    (maps,) = sample_token_maps(masked, None, [_job(conds, [7, 3], steps=5, guidance=1.0, greedy=True)])
    schedule = [remask_counts(7 * COLUMNS, 5), remask_counts(3 * COLUMNS, 5)]
    assert masked.masked_seen == [[schedule[0][n], schedule[1][n]] for n in range(5)]
    assert [m.shape for m in maps] == [(7, COLUMNS, 1), (3, COLUMNS, 1)]
    expected = (np.arange(7)[:, None] + np.arange(COLUMNS)[None, :]) % K       # greedy follows the favourite codes
    np.testing.assert_array_equal(maps[0][..., 0], expected)


def test_guidance_combines_cond_and_null_rows_per_stage():
    masked = ScriptedMasked()
    cond = np.eye(4)[1:2]
    (maps,) = sample_token_maps(masked, None, [_job(cond, [4], steps=3, guidance=0.0, greedy=True)])
    assert (maps[0] == 5).all()                       # s = 0: the null condition's logits alone
    assert len(masked.masked_seen[0]) == 2            # cond row + null row in one batch
    (maps,) = sample_token_maps(ScriptedMasked(), None, [_job(cond, [4], steps=3, guidance=3.0, greedy=True)])
    np.testing.assert_array_equal(maps[0][..., 0], (np.arange(4)[:, None] + np.arange(COLUMNS) + 1) % K)


def test_residual_layers_one_pass_each_and_pad_means_unused():
    residual = ScriptedResidual()
    (maps,) = sample_token_maps(ScriptedMasked(), residual, [_job(np.eye(4)[:1], [5], steps=2, greedy=True,
                                                                    guidance=1.0, residual_guidance=1.0)])
    assert residual.layers_seen == [1, 2]
    assert maps[0].shape == (5, COLUMNS, 3)
    assert (maps[0][..., 1] == 1).all()
    assert (maps[0][..., 2] == -1).all()             # a drawn pad id: the layer is unused there


def test_the_residual_stage_can_keep_its_own_temperature():
    """residual_temperature (MoMask's imports: 1) holds the residual stage while the mask stage's temperature
    changes; unset, the residual stage follows the job's temperature as before."""
    def residual_codes(**settings) -> np.ndarray:
        job = _job(np.eye(4)[:1], [40], seed=2, steps=2, guidance=1.0, residual_guidance=1.0, **settings)
        (maps,) = sample_token_maps(ScriptedMasked(), ScriptedResidual(), [job])
        return maps[0][..., 1]

    assert (residual_codes(temperature=1e-3) == 1).all()                # near greedy: layer 1 favours code 1
    assert (residual_codes(temperature=100.0) != 1).sum() > 20           # near uniform over the 9 classes
    assert (residual_codes(temperature=100.0, residual_temperature=1e-3) == 1).all()


class MaskClassResidual(ScriptedResidual):
    """MoGenTS's 2D residual vocabulary (K + 2: mask id K, pad K + 1): layer 1 draws the mask id where the
    condition's first entry is set, layer 2 draws pad everywhere."""

    layers, pad_id, mask_id = 3, K + 1, K

    def __call__(self, codes, layer, cond, length):
        self.layers_seen.append(int(layer[0]))
        batch, rows, columns, _ = codes.shape
        logits = np.zeros((batch, rows, columns, K + 2), np.float32)
        q = int(layer[0])
        logits[..., K + 1 if q == 2 else 3] = 5.0
        if q == 1:
            logits[cond[:, 0] > 0, ..., K] = 9.0
        return logits


def test_a_drawn_mask_id_clips_its_segments_map_only():
    """MoGenTS's rule: pad -> -1, and a segment whose map holds the mask id is clipped to [0, K - 1] (-1 -> 0, the
    mask id -> K - 1); the other segment keeps its -1 (unused layer)."""
    conds = np.eye(4)[:2]                                   # segment 0 draws the mask id at layer 1, segment 1 not
    (maps,) = sample_token_maps(ScriptedMasked(), MaskClassResidual(), [
        _job(conds, [3, 2], steps=2, greedy=True, guidance=1.0, residual_guidance=1.0)])
    assert (maps[0][..., 1] == K - 1).all() and (maps[0][..., 2] == 0).all()
    assert (maps[1][..., 1] == 3).all() and (maps[1][..., 2] == -1).all()


def test_branches_share_rows_and_join_along_the_columns():
    """Two generators on the same rows: the second's map after the first's columns; each job of a request draws
    from the request's generator in branch order, so a branch's settings are its own."""
    conds = np.eye(4)[:2]
    job = _job(conds, [5, 2], seed=4, steps=3, guidance=1.0, residual_guidance=1.0, top_k=1)
    job.branches = [replace(job, top_k=2, branches=[])]
    (maps,) = sample_branch_maps([(ScriptedMasked(), ScriptedResidual()), (ScriptedMasked(), ScriptedResidual())],
                                 [job])
    (first,) = sample_token_maps(ScriptedMasked(), ScriptedResidual(), [
        _job(conds, [5, 2], seed=4, steps=3, guidance=1.0, residual_guidance=1.0, top_k=1)])
    assert [m.shape for m in maps] == [(5, 2 * COLUMNS, 3), (2, 2 * COLUMNS, 3)]
    for joined, alone in zip(maps, first):
        np.testing.assert_array_equal(joined[:, :COLUMNS], alone)
    with pytest.raises(ValueError, match="1 branch job"):
        sample_branch_maps([(ScriptedMasked(), None)] * 2, [_job(conds, [2])])


def test_a_requests_tokens_do_not_depend_on_its_batch():
    conds = np.random.default_rng(1).normal(size=(3, 4))
    settings = {"steps": 4, "guidance": 2.0, "residual_guidance": 3.0, "top_k": 5, "temperature": 1.3}
    alone = sample_token_maps(ScriptedMasked(), ScriptedResidual(), [_job(conds[:2], [6, 2], seed=7, **settings)])
    crowded = sample_token_maps(ScriptedMasked(), ScriptedResidual(),
                                [_job(conds[2:], [9], seed=3, **settings), _job(conds[:2], [6, 2], seed=7, **settings),
                                 _job(conds[1:], [1, 4], seed=9, steps=4, guidance=1.0)])
    for a, b in zip(alone[0], crowded[1]):
        np.testing.assert_array_equal(a, b)
    other_seed = sample_token_maps(ScriptedMasked(), ScriptedResidual(), [_job(conds[:2], [6, 2], seed=8, **settings)])
    assert any((a != b).any() for a, b in zip(alone[0], other_seed[0]))


def test_cancelled_and_bad_jobs():
    cancelled = _job(np.eye(4)[:1], [3], cancelled=lambda: True)
    live = _job(np.eye(4)[:1], [3])
    results = sample_token_maps(ScriptedMasked(), None, [cancelled, live])
    assert results[0] is None and results[1] is not None
    with pytest.raises(ValueError, match=">= 1 token rows"):
        sample_token_maps(ScriptedMasked(), None, [_job(np.eye(4)[:1], [0])])
    with pytest.raises(ValueError, match="same number of steps"):
        sample_token_maps(ScriptedMasked(), None, [_job(np.eye(4)[:1], [2], steps=3), _job(np.eye(4)[:1], [2])])


def test_seeded_sampling_is_the_same_through_modules_and_graphs(tmp_path):
    """Not only greedy: with the same seed the PyTorch modules and their ONNX graphs draw the same tokens."""
    torch = pytest.importorskip("torch")
    from t2m.export.graphs.export import ort_session
    from t2m.families.masked.export_graphs import export_masked, export_residual
    from t2m.families.masked.masked_transformer import MaskedTransformer
    from t2m.families.masked.residual_transformer import ResidualTransformer
    from t2m.families.masked.sampling import generate_token_maps
    from t2m.model.networks.token_transformer import TokenTransformerConfig
    from t2m.runtime.onnx_step import OnnxMaskedStep, OnnxResidualStep

    torch.manual_seed(0)
    torch.set_num_threads(1)
    config = TokenTransformerConfig(codebook_size=16, code_dim=8, text_dim=8, columns=3, residual_layers=3,
                                    max_tokens=12, latent=32, n_head=2, ff_size=64, n_layer=1, dropout=0.0)
    masked, residual = MaskedTransformer(config).eval(), ResidualTransformer(config).eval()
    graphs = (OnnxMaskedStep(ort_session(export_masked(masked, tmp_path / "m.onnx")), 3, config.mask_id),
              OnnxResidualStep(ort_session(export_residual(residual, tmp_path / "r.onnx")), 3, residual.pad_id))
    cond = torch.randn(3, 8)
    for seed in range(3):
        settings = {"steps": 5, "guidance": 2.5, "residual_guidance": 3.0, "top_k": 6, "rng": seed}
        reference = generate_token_maps(masked, residual, cond, [5, 2, 7], **settings)
        served = generate_token_maps(*graphs, cond, [5, 2, 7], **settings)
        np.testing.assert_array_equal(reference, served)
