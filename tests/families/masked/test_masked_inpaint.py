"""The masked loop inpainting a map (t2m.decoding.inpaint): known tokens stay as they are on every layer, only the
tokens to fill are scheduled and drawn, the model sees the known ones, and the answer is the map's kept rows."""
from __future__ import annotations

import numpy as np
import pytest
from test_masked_loop import COLUMNS, MASK, ScriptedMasked, ScriptedResidual, _job

from t2m.decoding.inpaint import Inpaint
from t2m.families.masked.loop import remask_counts, sample_token_maps


def _map(rows: int, fill_rows: range, columns=slice(None)) -> Inpaint:
    rng = np.random.default_rng(4)
    known = rng.integers(0, MASK, (rows, COLUMNS, 3))
    known[rows - 1, 0, 2] = -1                             # an unused layer stays unused
    fill = np.zeros((rows, COLUMNS), dtype=bool)
    fill[fill_rows.start:fill_rows.stop, columns] = True
    return Inpaint(known, fill, (fill_rows.start, fill_rows.stop))


def test_known_tokens_are_kept_and_seen_and_only_the_fill_is_scheduled():
    masked, residual = ScriptedMasked(), ScriptedResidual()
    paint = _map(9, range(3, 6))
    job = _job(np.eye(4)[:1], [9], steps=4, guidance=1.0, greedy=True, inpaint=[paint])
    (maps,) = sample_token_maps(masked, residual, [job])
    assert masked.masked_seen == [[count] for count in remask_counts(3 * COLUMNS, 4)]   # the context is not masked
    (answer,) = maps
    assert answer.shape == (3, COLUMNS, 3)
    np.testing.assert_array_equal(answer[..., 0], (np.arange(3, 6)[:, None] + np.arange(COLUMNS)) % 8)
    assert (answer[..., 1] == 1).all()                    # the residual layers were drawn for the filled tokens


def test_a_part_of_the_columns_keeps_the_others_on_every_layer():
    paint = _map(6, range(0, 6), columns=slice(1, 2))
    job = _job(np.eye(4)[:1], [6], steps=3, guidance=1.0, inpaint=[paint])
    (maps,) = sample_token_maps(ScriptedMasked(), ScriptedResidual(), [job])
    np.testing.assert_array_equal(maps[0][:, 0], paint.known[:, 0])
    assert not np.array_equal(maps[0][:, 1], paint.known[:, 1])


def test_nothing_to_fill_answers_the_known_rows_and_a_plain_job_is_unchanged():
    paint = _map(5, range(1, 3), columns=slice(0, 0))
    plain = _job(np.eye(4)[1:2], [4], seed=7, steps=3)
    alone = sample_token_maps(ScriptedMasked(), ScriptedResidual(), [_job(np.eye(4)[1:2], [4], seed=7, steps=3)])
    both = sample_token_maps(ScriptedMasked(), ScriptedResidual(),
                             [plain, _job(np.eye(4)[:1], [5], steps=3, inpaint=[paint])])
    np.testing.assert_array_equal(both[1][0], paint.known[1:3])
    np.testing.assert_array_equal(both[0][0], alone[0][0])   # an inpainting job beside it changes nothing


def test_a_map_that_does_not_fit_is_refused():
    with pytest.raises(ValueError, match="keep"):
        Inpaint(np.zeros((3, COLUMNS, 1), np.int64), np.ones((3, COLUMNS), bool), (2, 5))
    job = _job(np.eye(4)[:1], [4], steps=2, inpaint=[_map(5, range(1, 2))])
    with pytest.raises(ValueError, match="inpainted map of 5 rows"):
        sample_token_maps(ScriptedMasked(), ScriptedResidual(), [job])
