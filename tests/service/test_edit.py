"""POST /edit and answers' handles: the handle's format and its checks as untrusted input,
what an edit keeps (the rule of docs/api.md, checked on arrays), determinism, and the 422s of families that cannot.

The rule: the answer's frames before the edited span are the handle's motion's bit for bit, up to the frames whose
decoded sources the decoder's reach of the first changed code step touches, and up to the segment whose time map
(engine/timeline.py) changed; the frames after it have bit-identical decoder rows outside the reach, but the root's
heading and position are running sums, so they are the original frames moved by one rigid motion (checked to 1e-4 m).
"""
from __future__ import annotations

import base64
import hashlib
import zlib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from t2m.runtime.engine import OnnxEngine
from t2m.runtime.handles import (
    CHECKSUM_BYTES,
    HANDLE_PREFIX,
    HandleError,
    make_handle,
    read_handle,
    segment_seed,
)
from t2m.runtime.timeline import segment_maps
from t2m.runtime.types import GenerationRequest, SegmentRequest, frames_for_duration
from t2m.service.settings import Settings

THREE = [("a person walks forward", 3.0), ("a person waves", 2.0), ("a person bows", 3.0)]


def request_of(segments, seed: int = 5, **options) -> GenerationRequest:
    return GenerationRequest([SegmentRequest(text, duration) for text, duration in segments], seed=seed, **options)


@pytest.fixture(scope="module")
def gpt_engine(random_bundle: Path) -> OnnxEngine:
    return OnnxEngine.load(random_bundle, intra_op_threads=1)


@pytest.fixture(scope="module")
def hifigpt_engine(hifigpt_bundle: Path) -> OnnxEngine:
    return OnnxEngine.load(hifigpt_bundle, intra_op_threads=1)


# ---------------------------------------------------------------- the rule, on arrays


def maps_of(engine: OnnxEngine, request: GenerationRequest, codes) -> list:
    per_token = engine.limits.frames_per_token
    return segment_maps(engine._targets(request), [len(c) * per_token for c in codes])


def guaranteed_prefix(engine: OnnxEngine, before: tuple, after: tuple, first_changed_step: int) -> int:
    """Output frames at the start that the rule says are bit-identical: (request, codes) before and after the
    edit; the first code step whose code differs (in both: the steps before it are the same)."""
    limit = (first_changed_step - engine.reach.ahead) * engine.limits.frames_per_token   # first decoded frame moved
    old_maps, new_maps = maps_of(engine, *before), maps_of(engine, *after)
    frames, decoded_start = 0, 0
    for old, new, codes in zip(old_maps, new_maps, before[1]):
        if old != new:
            return frames
        previous, weight = old.times()
        sources = decoded_start + previous + (weight > 0)
        inside = np.flatnonzero(sources >= limit)
        if inside.size:
            return frames + int(inside[0])
        frames += old.target
        decoded_start += len(codes) * engine.limits.frames_per_token
    return frames


def assert_rigidly_moved(new: np.ndarray, old: np.ndarray) -> None:
    """new = old turned about the vertical axis and shifted horizontally (one motion for all frames), to 1e-4 m."""
    assert new.shape == old.shape
    np.testing.assert_allclose(new[..., 1], old[..., 1], atol=1e-4)
    a = old[..., [0, 2]].reshape(-1, 2).astype(np.float64)
    b = new[..., [0, 2]].reshape(-1, 2).astype(np.float64)
    a0, b0 = a - a.mean(0), b - b.mean(0)
    angle = np.arctan2((a0[:, 0] * b0[:, 1] - a0[:, 1] * b0[:, 0]).sum(), (a0 * b0).sum())
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    np.testing.assert_allclose(a0 @ rotation.T, b0, atol=1e-4)


def sample_one(engine: OnnxEngine, text: str, duration: float, seed: int) -> np.ndarray:
    return engine.generate(request_of([(text, duration)], seed)).codes[0]


@pytest.mark.parametrize("which", ["gpt", "hifigpt"])
@pytest.mark.parametrize("edit", [(1, "a person raises the left hand", None), (1, None, 4.0),
                                  (2, "a person sits", None), (0, "a person jumps", 2.5)])
def test_frames_outside_the_edit_and_its_reach_are_kept(which, edit, gpt_engine, hifigpt_engine):
    engine = gpt_engine if which == "gpt" else hifigpt_engine
    index, text, duration = edit
    original = request_of(THREE)
    motion = engine.generate(original)
    segments = list(THREE)
    segments[index] = (text or THREE[index][0], duration or THREE[index][1])
    edited = request_of(segments)
    codes = list(motion.codes)
    codes[index] = sample_one(engine, segments[index][0], segments[index][1], segment_seed(5, index))
    answer = engine.compose(edited, codes)
    first = sum(len(c) for c in codes[:index])
    prefix = guaranteed_prefix(engine, (original, motion.codes), (edited, codes), first)
    assert np.array_equal(answer.joints[:prefix], motion.joints[:prefix])     # bit for bit
    assert not np.array_equal(answer.joints[:motion.segments[index].end_frame + 1],
                              motion.joints[:motion.segments[index].end_frame + 1])   # the edit did change frames
    # after the span: decoder rows bit-identical outside the reach, joints rigidly moved
    last = first + len(codes[index])
    step_after = last + engine.reach.behind + 1
    per_token = engine.limits.frames_per_token
    shift = (len(codes[index]) - len(motion.codes[index])) * per_token
    old_rows = engine.decoder.decode(np.concatenate(motion.codes))
    new_rows = engine.decoder.decode(np.concatenate(codes))
    assert np.array_equal(new_rows[step_after * per_token:], old_rows[step_after * per_token - shift:])
    if index + 1 < len(segments):   # the segment after the next one (its map and rows away from the edit)
        new_span, old_span = answer.segments[index + 2] if index + 2 < 3 else None, None
        if new_span is not None:
            old_span = motion.segments[index + 2]
            assert_rigidly_moved(answer.joints[new_span.start_frame:new_span.end_frame],
                                 motion.joints[old_span.start_frame:old_span.end_frame])


@pytest.mark.parametrize("which", ["gpt", "hifigpt"])
def test_append_keeps_the_motion_before_it(which, gpt_engine, hifigpt_engine):
    engine = gpt_engine if which == "gpt" else hifigpt_engine
    original = request_of(THREE[:2])
    motion = engine.generate(original)
    edited = request_of(THREE)
    codes = [*motion.codes, sample_one(engine, *THREE[2], 9)]
    answer = engine.compose(edited, codes)
    prefix = guaranteed_prefix(engine, (original, motion.codes), (request_of(THREE[:2]), motion.codes),
                               sum(len(c) for c in motion.codes))
    # the old last segment's map spans to its own last frame; with a segment after it, it spans to that one's first
    old_maps, new_maps = maps_of(engine, original, motion.codes), maps_of(engine, edited, codes)
    if old_maps[1] != new_maps[1]:
        prefix = min(prefix, motion.segments[1].start_frame)
    assert prefix > 0
    assert np.array_equal(answer.joints[:prefix], motion.joints[:prefix])


@pytest.mark.parametrize("which", ["gpt", "hifigpt"])
def test_unchanged_codes_give_the_motion_back_bit_for_bit(which, gpt_engine, hifigpt_engine):
    engine = gpt_engine if which == "gpt" else hifigpt_engine
    request = request_of([("a person walks forward", 3.0), ("a person turns", None), ("a person bows", 2.4)])
    motion = engine.generate(request)
    handle = read_handle(make_handle(engine.limits, request, motion.codes), engine.limits)
    again = engine.compose(handle.request(), [s.codes for s in handle.segments])
    assert np.array_equal(again.joints, motion.joints)
    assert again.segments == motion.segments


def test_masked_codes_round_trip_through_a_handle(masked_bundle):
    engine = OnnxEngine.load(masked_bundle, intra_op_threads=1)
    request = request_of([("a person walks forward", 2.0), ("a person kicks", 1.6)])
    motion = engine.generate(request)
    assert engine.limits.inpaints   # its edits: tests/families/masked/test_edit_masked.py
    handle = read_handle(make_handle(engine.limits, request, motion.codes), engine.limits)
    assert [s.codes.shape[1:] for s in handle.segments] == [engine.limits.codes.shape] * 2
    again = engine.compose(handle.request(), [s.codes for s in handle.segments])
    assert np.array_equal(again.joints, motion.joints)


# ---------------------------------------------------------------- the handle as untrusted input


def repack(handle: str, change) -> str:
    """The handle with its body changed by `change(body) -> body` and a correct checksum."""
    body = unpacked(handle)
    body = change(body)
    packed = hashlib.sha256(body).digest()[:CHECKSUM_BYTES] + zlib.compress(body)
    return HANDLE_PREFIX + base64.urlsafe_b64encode(packed).rstrip(b"=").decode()


def unpacked(handle: str) -> bytes:
    text = handle[len(HANDLE_PREFIX):]
    return zlib.decompress(base64.urlsafe_b64decode(text + "=" * (-len(text) % 4))[CHECKSUM_BYTES:])


@pytest.fixture(scope="module")
def made(gpt_engine):
    request = request_of(THREE, seed=11, guidance=2.0, top_k=20)
    motion = gpt_engine.generate(request)
    return request, motion, make_handle(gpt_engine.limits, request, motion.codes)


def test_a_handle_is_compact_and_holds_the_request(made, gpt_engine):
    _, motion, handle = made
    assert handle.startswith("t2m1.") and len(handle) < 400
    read = read_handle(handle, gpt_engine.limits)
    assert (read.model, read.version, read.seed, read.guidance, read.temperature, read.top_k) == (
        "t2m-random-test", gpt_engine.limits.version, 11, 2.0, 1.0, 20)
    assert [(s.text, s.duration) for s in read.segments] == THREE
    for kept, codes in zip(read.segments, motion.codes):
        assert np.array_equal(kept.codes, codes)


def set_meta(old: bytes, new: bytes):
    def change(body: bytes) -> bytes:
        assert old in body
        size = int.from_bytes(body[:4], "little") + len(new) - len(old)
        return size.to_bytes(4, "little") + body[4:].replace(old, new, 1)
    return change


def first_code(value: int):
    def change(body: bytes) -> bytes:
        size = int.from_bytes(body[:4], "little")
        return body[:4 + size] + value.to_bytes(2, "little") + body[4 + size + 2:]
    return change


@pytest.mark.parametrize("tamper, part, words", [
    (lambda h: h[:40] + ("A" if h[40] != "A" else "B") + h[41:], "handle", "corrupt"),
    (lambda h: h[:-6], "handle", ""),
    (lambda h: "t2m9." + h[5:], "handle", "starts with"),
    (lambda h: h + "!", "handle", "base64url"),
    (lambda h: repack(h, first_code(40)), "handle.segments.0.codes", "outside the codebook"),
    (lambda h: repack(h, set_meta(b'"steps":15', b'"steps":16')), "handle.segments.0.steps", "16 steps"),
    (lambda h: repack(h, set_meta(b'"steps":15', b'"steps":99')), "handle.segments.0.steps", "max_tokens"),
    (lambda h: repack(h, set_meta(b'"top_k":20', b'"top_k":999')), "handle.top_k", "got 999"),
    (lambda h: repack(h, set_meta(b'"seed":11', b'"seed":-1')), "handle.seed", "integer"),
    (lambda h: repack(h, set_meta(b'"seed":11', b'"seed":true')), "handle.seed", "integer"),
    (lambda h: repack(h, set_meta(b'"model":"t2m-random-test"', b'"model":"other"')), "handle.model", "other"),
    (lambda h: repack(h, set_meta(b'"shape":[]', b'"shape":[2]')), "handle.shape", "shape"),
    (lambda h: repack(h, set_meta(b'"text":"a person bows"', b'"text":""')), "handle.segments.2.text", ""),
    (lambda h: repack(h, set_meta(b'"duration":2.0', b'"duration":"2"')), "handle.segments.1.duration", ""),
    (lambda h: repack(h, lambda b: b + b"\0\0"), "handle.segments", "holds"),
    (lambda h: repack(h, lambda b: b[:4] + b"[]" + b[6:]), "handle", "JSON"),
])
def test_a_tampered_handle_is_refused_naming_the_part(made, gpt_engine, tamper, part, words):
    _, _, handle = made
    with pytest.raises(HandleError) as caught:
        read_handle(tamper(handle), gpt_engine.limits)
    assert caught.value.part == part, str(caught.value)
    assert words in str(caught.value)


def test_a_wrong_checksum_and_a_flipped_code_are_detected(made, gpt_engine):
    _, _, handle = made
    text = handle[len(HANDLE_PREFIX):]
    packed = bytearray(base64.urlsafe_b64decode(text + "=" * (-len(text) % 4)))
    packed[0] ^= 1
    wrong = HANDLE_PREFIX + base64.urlsafe_b64encode(bytes(packed)).rstrip(b"=").decode()
    with pytest.raises(HandleError, match="checksum") as caught:
        read_handle(wrong, gpt_engine.limits)
    assert caught.value.part == "handle.checksum"
    body = bytearray(unpacked(handle))
    body[-1] ^= 1   # a code changed, the checksum left as it was
    compressed = base64.urlsafe_b64decode(text + "=" * (-len(text) % 4))[:CHECKSUM_BYTES] + zlib.compress(bytes(body))
    with pytest.raises(HandleError) as caught:
        read_handle(HANDLE_PREFIX + base64.urlsafe_b64encode(compressed).rstrip(b"=").decode(), gpt_engine.limits)
    assert caught.value.part == "handle.checksum"


def test_another_version_and_a_zip_bomb_are_refused(made, gpt_engine):
    _, _, handle = made
    with pytest.raises(HandleError) as caught:
        read_handle(handle, replace(gpt_engine.limits, version="9.9.9"))
    assert caught.value.part == "handle.model" and "9.9.9" in str(caught.value)
    bomb = zlib.compress(b"\0" * 50_000_000)
    packed = hashlib.sha256(b"").digest()[:CHECKSUM_BYTES] + bomb
    with pytest.raises(HandleError, match="decompresses to more than"):
        read_handle(HANDLE_PREFIX + base64.urlsafe_b64encode(packed).decode(), gpt_engine.limits)


def test_segment_seeds_are_fixed_and_differ():
    assert segment_seed(5, 1) == segment_seed(5, 1)
    assert len({segment_seed(5, 0), segment_seed(5, 1), segment_seed(6, 1), segment_seed(5, "append")}) == 4
    assert 0 <= segment_seed(5, 1) < 2**31


# ---------------------------------------------------------------- over HTTP


def generate(client, segments=THREE, seed=5, **extra) -> dict:
    response = client.post("/generate", json={"segments": [{"text": t, "duration": d} for t, d in segments],
                                              "seed": seed, **extra})
    assert response.status_code == 200, response.text
    return response.json()


def edit(client, handle: str, edits, status: int = 200, **extra):
    response = client.post("/edit", json={"handle": handle, "edits": edits, **extra})
    assert response.status_code == status, response.text[:600]
    return response.json() if extra.get("format", "json") == "json" else response


def test_an_edit_keeps_the_other_segments_and_is_deterministic(app_client, gpt_engine):
    original = generate(app_client)
    assert original["handle"].startswith("t2m1.")
    same = edit(app_client, original["handle"], [])
    assert same["frames"] == original["frames"] and same["segments"] == original["segments"]
    assert same["handle"] == original["handle"] and same["edited"] == []

    change = [{"segment": 1, "text": "a person raises the left hand"}]
    first = edit(app_client, original["handle"], change)
    again = edit(app_client, original["handle"], change)
    assert first == again
    assert first["edited"] == [{"segment": 1, "seed": segment_seed(5, 1)}]
    assert [s["text"] for s in first["segments"]] == [THREE[0][0], "a person raises the left hand", THREE[2][0]]
    kept = (15 - gpt_engine.reach.ahead) * 4   # durations of whole tokens: every time map is the identity
    assert first["frames"][:kept] == original["frames"][:kept]
    assert first["frames"][kept + 4:] != original["frames"][kept + 4:]
    old, new = read_handle(original["handle"], gpt_engine.limits), read_handle(first["handle"], gpt_engine.limits)
    assert np.array_equal(new.segments[0].codes, old.segments[0].codes)
    assert np.array_equal(new.segments[2].codes, old.segments[2].codes)
    # the edited segment is that text sampled alone with its seed, as /generate samples it
    alone = generate(app_client, [("a person raises the left hand", 2.0)], seed=segment_seed(5, 1))
    assert np.array_equal(new.segments[1].codes, read_handle(alone["handle"], gpt_engine.limits).segments[0].codes)
    # an explicit seed re-rolls; the same seed gives the same segment
    rolled = edit(app_client, original["handle"], [{"segment": 1, "seed": 77}])
    assert rolled["edited"] == [{"segment": 1, "seed": 77}]
    assert rolled == edit(app_client, original["handle"], [{"segment": 1, "seed": 77}])
    assert rolled["frames"] != first["frames"]
    # editing the edited motion's handle with no edits gives it back
    assert edit(app_client, first["handle"], [])["frames"] == first["frames"]


def test_append_and_prepend_sample_the_new_segments_as_generate_would(app_client, gpt_engine):
    original = generate(app_client, THREE[:2])
    added = [{"text": "a person sits down", "duration": 2.0}]
    appended = edit(app_client, original["handle"], [{"op": "append", "segments": added, "seed": 3}])
    assert [s["text"] for s in appended["segments"]] == [THREE[0][0], THREE[1][0], "a person sits down"]
    assert appended["edited"] == [{"segment": 2, "seed": 3}]
    assert appended["frames"][:60] == original["frames"][:60]
    alone = generate(app_client, [("a person sits down", 2.0)], seed=3)
    new = read_handle(appended["handle"], gpt_engine.limits)
    assert np.array_equal(new.segments[2].codes, read_handle(alone["handle"], gpt_engine.limits).segments[0].codes)
    both = edit(app_client, original["handle"], [{"op": "prepend", "segments": added},
                                                 {"segment": 0, "text": "a person runs"}])
    assert [s["text"] for s in both["segments"]] == ["a person sits down", "a person runs", THREE[1][0]]
    assert both["edited"] == [{"segment": 0, "seed": segment_seed(5, "prepend")},
                              {"segment": 1, "seed": segment_seed(5, 0)}]
    assert both["segments"][0]["end_frame"] == frames_for_duration(2.0)


@pytest.mark.parametrize("edits, loc, words", [
    ([{"segment": 3}], ["body", "edits", 0, "segment"], "0..2"),
    ([{"segment": 1}, {"segment": 1, "seed": 2}], ["body", "edits", 1, "segment"], "twice"),
    ([{"segment": 1, "duration": 0.1}], ["body", "edits", 0, "regenerate", "duration"], "greater than"),
    ([{"op": "insert", "segments": []}], ["body", "edits", 0, "regenerate", "op"], "regenerate"),
    ([{"op": "append", "segments": [{"text": "a person sits", "duration": 10.0}] * 12}], ["body", "edits"], "120"),
])
def test_edits_out_of_range_are_422_naming_the_field(app_client, edits, loc, words):
    original = generate(app_client)
    detail = edit(app_client, original["handle"], edits, status=422)["detail"]
    assert detail[0]["loc"] == loc and words in detail[0]["msg"], detail


def test_a_tampered_handle_over_http_is_422_naming_the_handle(app_client, made):
    original = generate(app_client)
    handle = original["handle"]
    for bad in (handle[:30] + ("A" if handle[30] != "A" else "B") + handle[31:],
                repack(handle, first_code(40)), "t2m1.", "nonsense"):
        detail = edit(app_client, bad, [], status=422)["detail"]
        assert detail[0]["loc"] == ["body", "handle"], detail
    other = repack(handle, set_meta(b'"version":"', b'"version":"9'))
    detail = edit(app_client, other, [], status=422)["detail"]
    assert detail[0]["loc"] == ["body", "handle"] and "handle.model" in detail[0]["msg"]
    unserved = repack(handle, set_meta(b'"model":"t2m-random-test"', b'"model":"elsewhere"'))
    detail = edit(app_client, unserved, [], status=422)["detail"]
    assert detail[0]["loc"] == ["body", "handle"] and "does not serve" in detail[0]["msg"]
    detail = edit(app_client, handle, [], status=422, model="no-such-model")["detail"]
    assert detail[0]["loc"] == ["body", "model"]


def test_edit_answers_bvh_and_the_stream_ends_with_the_handle(app_client):
    original = generate(app_client)
    response = edit(app_client, original["handle"], [{"segment": 2, "seed": 4}], format="bvh")
    assert response.text.startswith("HIERARCHY") and response.headers["X-Seed"] == "5"
    lines = app_client.post("/generate", json={"segments": [{"text": "a person walks forward", "duration": 3.0},
                                                            {"text": "a person waves", "duration": 2.0},
                                                            {"text": "a person bows", "duration": 3.0}],
                                               "seed": 5, "stream": True}).text.splitlines()
    import json

    assert json.loads(lines[-1])["handle"] == original["handle"]


def test_two_models_each_edit_their_own_handles(make_client, random_bundle, hifigpt_bundle, hifigpt_engine):
    client = make_client(Settings(bundle_path=random_bundle, extra_model_dirs=[hifigpt_bundle], intra_op_threads=1))
    name = hifigpt_engine.limits.name
    original = generate(client, model=name)
    answer = edit(client, original["handle"], [{"segment": 2, "text": "a person sits"}])   # the handle's model
    assert answer["model"]["name"] == name and answer["frames"][:60] == original["frames"][:60]
    detail = edit(client, original["handle"], [], status=422, model="t2m-random-test")["detail"]
    assert detail[0]["loc"] == ["body", "handle"] and "handle.model" in detail[0]["msg"]


def test_kinds_a_family_does_not_declare_are_refused_naming_them(app_client):
    """The GPT family samples segments alone: it declares no in_between or body_part (the masked family does)."""
    health = app_client.get("/health").json()
    assert health["model"]["extra"]["edits"] == ["append", "prepend", "regenerate"]
    original = generate(app_client)
    for kind in ({"op": "in_between", "after": 0, "text": "a person turns", "duration": 1.0},
                 {"op": "body_part", "segment": 0, "part": "upper_body"}):
        detail = edit(app_client, original["handle"], [kind], status=422)["detail"]
        assert detail[0]["loc"] == ["body", "edits", 0, "op"]
        assert "family 'gpt'" in detail[0]["msg"] and kind["op"] in detail[0]["msg"]


def test_openapi_documents_edit_with_examples(app_client):
    schema = app_client.get("/openapi.json").json()
    operation = schema["paths"]["/edit"]["post"]
    assert "422" in operation["responses"]
    assert schema["components"]["schemas"]["EditRequest"]["examples"]
    assert "handle" in schema["components"]["schemas"]["MotionResponse"]["properties"]
    assert schema["paths"]["/generate"]["post"]["responses"]["200"]


def test_the_sdk_edits_a_motion_it_generated(live_server):
    import asyncio

    from t2m.client import Append, AsyncT2MClient, Regenerate, T2MClient, ValidationError

    with T2MClient(live_server.url, api_key="test-key") as t2m:
        motion = t2m.generate(THREE, seed=5)
        assert motion.handle and motion.handle.startswith("t2m1.")
        same = t2m.edit(motion)
        assert np.array_equal(same.frames, motion.frames) and same.edited == []
        edited = t2m.edit(motion, [Regenerate(1, text="a person raises the left hand", seed=3),
                                   Append([("a person sits down", 2.0)], seed=4)])
        assert edited.edited == [(1, 3), (3, 4)] and len(edited.segments) == 4
        assert np.array_equal(edited.frames[:40], motion.frames[:40])
        assert t2m.edit(edited.handle, [{"segment": 3, "seed": 4}]).handle == edited.handle   # the same sample
        bvh = t2m.edit_raw(motion, [Regenerate(2, seed=1)], "bvh")
        assert bvh.content.startswith(b"HIERARCHY") and bvh.seed == 5
        with pytest.raises(ValidationError) as caught:
            t2m.edit(motion.handle[:-8], [])
        assert caught.value.fields == ["handle"]

    async def scenario() -> None:
        async with AsyncT2MClient(live_server.url, api_key="test-key") as t2m:
            again = await t2m.edit(motion.handle, [Regenerate(1, text="a person raises the left hand", seed=3),
                                                   Append([("a person sits down", 2.0)], seed=4)])
            assert np.array_equal(again.frames, edited.frames)

    asyncio.run(scenario())


def test_t2m_edit_changes_a_saved_json_motion(random_bundle, tmp_path, capsys):
    import json

    from t2m.cli.main import main

    saved = tmp_path / "walk.json"
    assert main(["generate", "a person walks forward", "--duration", "3", "--then", "a person waves", "--duration",
                 "2", "--then", "a person bows", "--duration", "3", "--seed", "5", "--model", str(random_bundle),
                 "-o", str(saved)]) == 0
    original = json.loads(saved.read_text())
    edited_path = tmp_path / "edited.json"
    assert main(["edit", str(saved), "--segment", "1", "--text", "a person raises the left hand",
                 "--model", str(random_bundle), "-o", str(edited_path)]) == 0
    edited = json.loads(edited_path.read_text())
    assert edited["edited"] == [{"segment": 1, "seed": segment_seed(5, 1)}]
    assert edited["frames"][:40] == original["frames"][:40] and edited["frames"] != original["frames"]
    bvh = tmp_path / "longer.bvh"
    assert main(["edit", str(edited_path), "--edits", '[{"op": "append", "segments": [{"text": "a person sits", '
                 '"duration": 2}]}]', "--model", str(random_bundle), "-o", str(bvh)]) == 0
    assert bvh.read_text().startswith("HIERARCHY")
    capsys.readouterr()
    saved.write_text(json.dumps({**original, "handle": original["handle"][:-5]}))
    assert main(["edit", str(saved), "--model", str(random_bundle), "-o", str(tmp_path / "x.json")]) == 2
    assert "handle" in capsys.readouterr().err
