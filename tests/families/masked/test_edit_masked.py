"""POST /edit on the masked family: an edit's tokens are masked and filled by the family's own re-masking
loop with the kept tokens on both sides as context, then the residual stage, then one decode of the whole motion.

Checked on arrays with a tiny random 2D (joint-token) bundle: the kept segments' codes come back as they were, the
frames outside the edit and outside the decoder's reach of it are the handle's bit for bit (the rule of
docs/api.md, as tests/service/test_edit.py checks it for the autoregressive families; this decoder's reach is
measured here, its streaming does not need it), a body-part edit keeps the other columns' codes, the same edit and
seed give the same answer, and the refusals are 422s naming the field.
"""
from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from t2m.api import EditRequest
from t2m.runtime.editing import EditError, edit_in_process, plan_edit
from t2m.runtime.engine import OnnxEngine
from t2m.runtime.handles import make_handle, read_handle, segment_seed
from t2m.runtime.reach import probe_reach
from t2m.service.settings import Settings
from tests.service.test_edit import THREE, assert_rigidly_moved, edit, generate, guaranteed_prefix, request_of


@pytest.fixture(scope="module")
def engine(masked_bundle: Path) -> OnnxEngine:
    return OnnxEngine.load(masked_bundle, intra_op_threads=1)


@pytest.fixture(scope="module")
def reached(engine: OnnxEngine) -> SimpleNamespace:
    """The engine as guaranteed_prefix reads it, with its decoder's reach measured on whole code rows [C, R]."""
    shape = engine.limits.codes.shape
    reach = probe_reach(lambda codes: engine.decoder.decode(codes.reshape(len(codes), *shape)),
                        engine.limits.codebook_size, engine.limits.frames_per_token, depth=int(np.prod(shape)))
    assert reach is not None
    return SimpleNamespace(reach=reach, limits=engine.limits, _targets=engine._targets)


@pytest.fixture(scope="module")
def original(engine: OnnxEngine):
    request = request_of(THREE)
    motion = engine.generate(request)
    return request, motion, make_handle(engine.limits, request, motion.codes)


def edits_of(*edits: dict) -> list:
    return EditRequest.model_validate({"handle": "t2m1.x", "edits": list(edits)}).edits


def run(engine: OnnxEngine, handle: str, *edits: dict):
    return edit_in_process(engine, handle, edits_of(*edits))


def decoded(engine: OnnxEngine, codes) -> np.ndarray:
    return engine.decoder.decode(np.concatenate(codes))


def assert_rows_after_kept(engine, reached, old_codes, new_codes, last_new_step: int, shift_steps: int) -> None:
    """Decoder rows from the reach after the last changed step on are the old ones, moved by `shift_steps`."""
    per_token = engine.limits.frames_per_token
    after = (last_new_step + reached.reach.behind + 1) * per_token
    old_rows, new_rows = decoded(engine, old_codes), decoded(engine, new_codes)
    assert after < len(new_rows)
    assert np.array_equal(new_rows[after:], old_rows[after - shift_steps * per_token:])


def test_the_family_declares_its_edits(engine, masked_1d_bundle_path):
    assert engine.limits.edits == frozenset({"regenerate", "append", "prepend", "in_between", "body_part"})
    assert engine.limits.inpaints and engine.limits.body_parts == {"upper_body": (3, 4, 5), "lower_body": (0, 2)}
    one_column = OnnxEngine.load(masked_1d_bundle_path, intra_op_threads=1)
    assert "body_part" not in one_column.limits.edits and one_column.limits.body_parts == {}


@pytest.mark.parametrize("change", [{"segment": 1, "text": "a person raises the left hand"},
                                   {"segment": 1, "duration": 4.0},
                                   {"segment": 2, "text": "a person sits"},
                                   {"segment": 0, "text": "a person jumps", "duration": 2.4}])
def test_regenerate_inpaints_the_segment_and_keeps_the_rest(engine, reached, original, change):
    request, motion, handle = original
    answer = run(engine, handle, change)
    index = change["segment"]
    new = read_handle(answer.handle, engine.limits)
    codes = [s.codes for s in new.segments]
    for other in set(range(3)) - {index}:
        assert np.array_equal(codes[other], motion.codes[other])        # kept codes, all layers
    assert not np.array_equal(codes[index], motion.codes[index][:len(codes[index])])
    assert answer.edited == [(index, segment_seed(5, index))]
    edited_request = new.request()
    first = sum(len(c) for c in codes[:index])
    prefix = guaranteed_prefix(reached, (request, motion.codes), (edited_request, codes), first)
    assert np.array_equal(answer.motion.joints[:prefix], motion.joints[:prefix])   # bit for bit
    if index < 2:   # after the edit: decoder rows outside the reach kept; the segment after the next rigidly moved
        assert_rows_after_kept(engine, reached, motion.codes, codes, first + len(codes[index]) - 1,
                               len(codes[index]) - len(motion.codes[index]))
    if index == 0:
        assert_rigidly_moved(answer.motion.joints[answer.motion.segments[2].start_frame:],
                             motion.joints[motion.segments[2].start_frame:])


def test_the_context_on_both_sides_shapes_the_filled_tokens(engine, original):
    """The same text and seed sampled alone (no context) gives other codes than the inpainted edit."""
    _, _, handle = original
    answer = run(engine, handle, {"segment": 1, "text": "a person waves", "seed": 3})
    alone = engine.generate(request_of([("a person waves", 2.0)], seed=3)).codes[0]
    assert not np.array_equal(read_handle(answer.handle, engine.limits).segments[1].codes, alone)


def test_the_same_edit_and_seed_give_the_same_answer(engine, original):
    _, _, handle = original
    edits = ({"segment": 1, "text": "a person raises the left hand"}, {"op": "append", "segments": [
        {"text": "a person sits down", "duration": 1.6}], "seed": 4}, {"op": "in_between", "after": 0,
                                                                       "text": "a person turns", "duration": 1.2})
    first, again = run(engine, handle, *edits), run(engine, handle, *edits)
    assert np.array_equal(first.motion.joints, again.motion.joints) and first.handle == again.handle
    rolled = run(engine, handle, {"segment": 1, "seed": 77})
    assert rolled.edited == [(1, 77)] and not np.array_equal(rolled.motion.joints, first.motion.joints)
    assert np.array_equal(run(engine, handle, {"segment": 1, "seed": 77}).motion.joints, rolled.motion.joints)


def test_append_and_prepend_keep_the_motion(engine, reached, original):
    request, motion, handle = original
    answer = run(engine, handle, {"op": "append", "segments": [{"text": "a person sits down", "duration": 2.0}],
                                  "seed": 3})
    codes = [s.codes for s in read_handle(answer.handle, engine.limits).segments]
    assert all(np.array_equal(a, b) for a, b in zip(codes, motion.codes)) and len(codes) == 4
    prefix = min(guaranteed_prefix(reached, (request, motion.codes), (request, motion.codes),
                                   sum(len(c) for c in motion.codes)), motion.segments[2].start_frame)
    assert prefix > 0 and np.array_equal(answer.motion.joints[:prefix], motion.joints[:prefix])
    before = run(engine, handle, {"op": "prepend", "segments": [{"text": "a person stands up", "duration": 1.6}]})
    codes = [s.codes for s in read_handle(before.handle, engine.limits).segments]
    assert all(np.array_equal(a, b) for a, b in zip(codes[1:], motion.codes)) and len(codes) == 4
    assert_rows_after_kept(engine, reached, motion.codes, codes, len(codes[0]) - 1, len(codes[0]))
    assert before.edited == [(0, segment_seed(5, "prepend"))]


def test_in_between_fills_a_gap_keeping_both_sides(engine, reached, original):
    request, motion, handle = original
    answer = run(engine, handle, {"op": "in_between", "after": 1, "text": "a person turns around", "duration": 1.6})
    new = read_handle(answer.handle, engine.limits)
    assert [s.text for s in new.segments] == [THREE[0][0], THREE[1][0], "a person turns around", THREE[2][0]]
    assert [s.duration for s in new.segments] == [3.0, 2.0, 1.6, 3.0]
    codes = [s.codes for s in new.segments]
    kept = [codes[0], codes[1], codes[3]]
    assert all(np.array_equal(a, b) for a, b in zip(kept, motion.codes))
    assert answer.edited == [(2, segment_seed(5, "in_between.1"))]
    first = len(codes[0]) + len(codes[1])
    prefix = guaranteed_prefix(reached, (request, motion.codes), (new.request(), codes), first)
    # the segment before the gap is no longer the last: its time map may change; every rate here is 1 (whole steps)
    assert prefix > 0 and np.array_equal(answer.motion.joints[:prefix], motion.joints[:prefix])
    assert_rows_after_kept(engine, reached, motion.codes, codes, first + len(codes[2]) - 1, len(codes[2]))


def test_body_part_keeps_the_other_joints_tokens(engine, reached, original):
    request, motion, handle = original
    answer = run(engine, handle, {"op": "body_part", "segment": 1, "part": "upper_body",
                                  "text": "a person waves with both hands"})
    new = read_handle(answer.handle, engine.limits)
    codes = [s.codes for s in new.segments]
    assert new.segments[1].text == "a person waves with both hands" and new.segments[1].duration == 2.0
    assert np.array_equal(codes[1][:, [0, 1, 2]], motion.codes[1][:, [0, 1, 2]])      # legs and spine kept
    assert not np.array_equal(codes[1][:, [3, 4, 5]], motion.codes[1][:, [3, 4, 5]])
    assert np.array_equal(codes[0], motion.codes[0]) and np.array_equal(codes[2], motion.codes[2])
    assert answer.edited == [(1, segment_seed(5, "body_part.1"))]
    first = len(codes[0]) + int(np.flatnonzero((codes[1] != motion.codes[1]).any(axis=(1, 2)))[0])
    prefix = guaranteed_prefix(reached, (request, motion.codes), (new.request(), codes), first)
    assert prefix > 0 and np.array_equal(answer.motion.joints[:prefix], motion.joints[:prefix])
    # a span within the segment: the rows outside it are kept in every column
    span = run(engine, handle, {"op": "body_part", "segment": 2, "part": "lower_body", "start": 1.0, "end": 2.0})
    rows = read_handle(span.handle, engine.limits).segments[2].codes
    assert np.array_equal(rows[:5], motion.codes[2][:5]) and np.array_equal(rows[10:], motion.codes[2][10:])
    assert np.array_equal(rows[:, [1, 3, 4, 5]], motion.codes[2][:, [1, 3, 4, 5]])


@pytest.mark.parametrize("change, loc, words", [
    ({"op": "in_between", "after": 2, "text": "a person turns", "duration": 1.0}, ("after",), "0..1"),
    ({"op": "body_part", "segment": 1, "part": "upper_body", "start": 2.0, "end": 2.5}, ("end",), "no code step"),
    ({"op": "append", "segments": [{"text": "a person sits", "duration": None}]}, ("segments", 0, "duration"),
     "give a duration"),
])
def test_masked_edits_out_of_range_name_the_field(engine, original, change, loc, words):
    _, _, handle = original
    with pytest.raises(EditError) as caught:
        plan_edit(read_handle(handle, engine.limits), edits_of(change), engine.limits)
    assert caught.value.loc == ("body", "edits", 0, *loc) and words in str(caught.value), str(caught.value)


# ---------------------------------------------------------------- over HTTP


@pytest.fixture(scope="module")
def masked_1d_bundle_path(tmp_path_factory) -> Path:
    from t2m.families.masked.random_bundle import build_random_masked_bundle

    return build_random_masked_bundle(tmp_path_factory.mktemp("masked") / "1d", variant="1d", residual_layers=2,
                                      length_estimator=False, name="t2m-random-masked-1d")


def test_over_http_edits_and_refusals(make_client, masked_bundle, random_bundle, masked_1d_bundle_path):
    client = make_client(Settings(bundle_path=masked_bundle, extra_model_dirs=[random_bundle, masked_1d_bundle_path],
                                  intra_op_threads=1))
    health = client.get("/health").json()
    assert health["model"]["extra"]["edits"] == ["append", "body_part", "in_between", "prepend", "regenerate"]
    made = generate(client, THREE[:2])
    gap = {"op": "in_between", "after": 0, "text": "a person turns", "duration": 1.2}
    answer = edit(client, made["handle"], [gap])
    assert answer == edit(client, made["handle"], [gap]) and len(answer["segments"]) == 3
    assert answer["frames"][:20] == made["frames"][:20]
    upper = {"op": "body_part", "segment": 1, "part": "upper_body", "seed": 2}
    assert edit(client, made["handle"], [upper])["edited"] == [{"segment": 1, "seed": 2}]
    # a handle of another model: 422 naming the handle's model
    detail = edit(client, made["handle"], [], status=422, model="t2m-random-test")["detail"]
    assert detail[0]["loc"] == ["body", "handle"] and "handle.model" in detail[0]["msg"]
    # the new kinds on families that do not declare them: 422 naming the op
    gpt = generate(client, THREE, model="t2m-random-test")
    for kind in (gap, {**upper, "seed": None}):
        detail = edit(client, gpt["handle"], [kind], status=422)["detail"]
        assert detail[0]["loc"] == ["body", "edits", 0, "op"] and "family 'gpt'" in detail[0]["msg"], detail
    flat = generate(client, THREE[:2], model="t2m-random-masked-1d")
    detail = edit(client, flat["handle"], [upper], status=422)["detail"]
    assert detail[0]["loc"] == ["body", "edits", 0, "op"] and "body_part" in detail[0]["msg"]
    assert edit(client, flat["handle"], [gap])["segments"][1]["text"] == "a person turns"


def test_the_sdk_objects_are_the_api_edits(engine, original):
    from t2m.client import BodyPart, InBetween
    from t2m.client.models import edits_json

    _, _, handle = original
    objects = edits_json([InBetween(0, "a person turns", 1.2, seed=3), BodyPart(2, "lower_body", start=1.0)])
    assert objects == [{"op": "in_between", "after": 0, "text": "a person turns", "duration": 1.2, "seed": 3},
                       {"op": "body_part", "segment": 2, "part": "lower_body", "start": 1.0}]
    assert run(engine, handle, *objects).handle == run(engine, handle, *[dict(o) for o in objects]).handle
