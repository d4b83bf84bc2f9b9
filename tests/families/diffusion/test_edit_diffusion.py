"""POST /edit on the diffusion family: a diffusion answer's handle is a recipe (service/recipes.py) that
makes its frames again bit for bit; in_between and body_part edits are made by the loop's inpainting on the tiny
random MDM and DiP bundles (service/diffusion_edits.py).

Checked on arrays: every kept segment's normalised frames are the handle's (a body_part edit's known channels too),
the decoded frames before the edit are the handle's bit for bit and the ones after an in-between the same motion
rigidly moved (the root's path is a running sum); the same edit and seed give the same answer, another seed
another; the recipe of an edited motion replays it exactly. Over HTTP: the edits, the kinds MDM / DiP do not
declare, another model's handle and tampered handles, all 422s naming the field.
"""
from __future__ import annotations

import base64
import hashlib
import json
import zlib
from dataclasses import replace

import numpy as np
import pytest
import torch

from t2m.api import EditRequest
from t2m.families.diffusion.edits import edit_recipe, replay
from t2m.families.diffusion.loop import numbered_join_windows
from t2m.families.diffusion.random_bundle import build_random_diffusion_bundle
from t2m.runtime.editing import EditError
from t2m.runtime.engine import OnnxEngine
from t2m.runtime.handles import HandleError, handle_model, make_handle, segment_seed
from t2m.runtime.recipes import MAX_EDIT_STEPS, RECIPE_PREFIX, read_recipe
from t2m.runtime.types import GenerationRequest, SegmentRequest
from t2m.service.settings import Settings
from tests.service.test_edit import assert_rigidly_moved

torch.set_num_threads(1)

THREE = [("a person walks forward", 1.0), ("a person waves with the right hand", 1.5), ("a person bows", 0.65)]
ARCHS = ["mdm", "dip"]


@pytest.fixture(scope="module")
def bundles(tmp_path_factory):
    root = tmp_path_factory.mktemp("diffusion-edits")
    for arch in ARCHS:
        build_random_diffusion_bundle(root / arch, arch=arch, seed=5)
    return root


@pytest.fixture(scope="module")
def engines(bundles):
    return {arch: OnnxEngine.load(bundles / arch, intra_op_threads=1) for arch in ARCHS}


@pytest.fixture(scope="module")
def originals(engines):
    """arch -> (request, motion, handle) of a three-sentence request."""
    out = {}
    for arch, engine in engines.items():
        request = GenerationRequest([SegmentRequest(text, duration) for text, duration in THREE], seed=11,
                                    guidance=2.5)
        motion = engine.generate(request)
        out[arch] = request, motion, make_handle(engine.limits, request, motion.codes)
    return out


def edits_of(*edits: dict) -> list:
    return EditRequest.model_validate({"handle": "t2m2.x", "edits": list(edits)}).edits


def run(engine, handle, *edits: dict):
    return edit_recipe(engine, handle, edits_of(*edits))


def frames_of(engine, handle) -> list[np.ndarray]:
    segments, _ = replay(engine, read_recipe(handle, engine.limits))
    return [s.frames for s in segments]


def recipe_json(handle: str) -> dict:
    text = handle[len(RECIPE_PREFIX):]
    packed = base64.urlsafe_b64decode(text + "=" * (-len(text) % 4))
    return json.loads(zlib.decompress(packed[16:]))


def recipe_of(body: dict) -> str:
    """A recipe of any content, its checksum right (a client can make one: everything in it is checked)."""
    data = json.dumps(body, separators=(",", ":")).encode()
    packed = hashlib.sha256(data).digest()[:16] + zlib.compress(data)
    return RECIPE_PREFIX + base64.urlsafe_b64encode(packed).rstrip(b"=").decode()


@pytest.mark.parametrize("arch", ARCHS)
def test_both_declare_their_edits_and_body_parts_are_mdms_channels(engines, arch):
    limits = engines[arch].limits
    assert limits.edits == frozenset({"regenerate", "append", "prepend", "in_between", "body_part"})
    assert limits.recipe and limits.codes is None
    lower = limits.body_parts["lower_body"]
    assert len(lower) == 107 and len(limits.body_parts["upper_body"]) == 263 - 107   # MDM's HML_LOWER_BODY_MASK
    assert set(lower) >= {0, 1, 2, 3, 259, 260, 261, 262} and not set(lower) & set(limits.body_parts["upper_body"])


@pytest.mark.parametrize("arch", ARCHS)
def test_the_handle_is_a_recipe_that_makes_the_frames_again_bit_for_bit(engines, originals, arch):
    engine = engines[arch]
    _, motion, handle = originals[arch]
    assert handle.startswith(RECIPE_PREFIX) and len(handle) < 400
    assert handle_model(handle) == (engine.limits.name, engine.limits.version)
    recipe = read_recipe(handle, engine.limits)
    assert recipe.seed == 11 and recipe.guidance == 2.5 and recipe.edits == []
    for again, frames in zip(frames_of(engine, handle), motion.codes):
        assert again.dtype == np.float32 and np.array_equal(again, frames)
    answer = run(engine, handle)
    assert np.array_equal(answer.motion.joints, motion.joints) and answer.handle == handle and answer.edited == []


@pytest.mark.parametrize("arch", ARCHS)
def test_in_between_keeps_both_sides(engines, originals, arch):
    engine = engines[arch]
    _, motion, handle = originals[arch]
    answer = run(engine, handle, {"op": "in_between", "after": 0, "text": "a person turns around", "duration": 1.2,
                                  "seed": 3})
    assert answer.edited == [(1, 3)]
    frames = frames_of(engine, answer.handle)
    assert [len(f) for f in frames] == [20, 24, 30, 13]
    for kept, old in zip([frames[0], *frames[2:]], motion.codes):
        assert np.array_equal(kept, old)                                  # normalised frames, bit for bit
    assert np.isfinite(frames[1]).all() and not np.array_equal(frames[1][:20], motion.codes[1][:20])
    joints, spans = answer.motion.joints, answer.motion.segments
    assert [(s.start_frame, s.end_frame) for s in spans] == [(0, 20), (20, 44), (44, 74), (74, 87)]
    assert np.array_equal(joints[:20], motion.joints[:20])                # before the edit: bit for bit
    assert_rigidly_moved(joints[44:], motion.joints[20:])                 # after it: the same motion, moved


@pytest.mark.parametrize("arch", ARCHS)
@pytest.mark.parametrize("part", ["upper_body", "lower_body"])
def test_body_part_regenerates_only_the_parts_channels_over_the_span(engines, originals, arch, part):
    engine = engines[arch]
    _, motion, handle = originals[arch]
    answer = run(engine, handle, {"op": "body_part", "segment": 1, "part": part, "start": 0.25, "end": 1.0,
                                  "text": "a person waves with both hands"})
    assert answer.edited == [(1, segment_seed(11, "body_part.1"))]
    frames = frames_of(engine, answer.handle)
    assert np.array_equal(frames[0], motion.codes[0]) and np.array_equal(frames[2], motion.codes[2])
    channels = list(engine.limits.body_parts[part])
    known = np.ones_like(motion.codes[1], dtype=bool)
    known[5:20, channels] = False                                         # 0.25-1.0 s: frames 5..19
    assert np.array_equal(frames[1][known], motion.codes[1][known])       # every known channel exactly
    assert (frames[1][~known] != motion.codes[1][~known]).mean() > 0.9
    assert np.array_equal(answer.motion.joints[:20], motion.joints[:20])
    assert answer.motion.segments[1].text == "a person waves with both hands"


@pytest.mark.parametrize("arch", ARCHS)
def test_the_same_edit_and_seed_give_the_same_answer_another_seed_another(engines, originals, arch):
    engine = engines[arch]
    _, _, handle = originals[arch]
    edits = ({"op": "body_part", "segment": 0, "part": "upper_body", "seed": 4},
             {"op": "in_between", "after": 1, "text": "a person steps back", "duration": 0.8})
    first, again = run(engine, handle, *edits), run(engine, handle, *edits)
    assert np.array_equal(first.motion.joints, again.motion.joints) and first.handle == again.handle
    assert first.edited == [(0, 4), (2, segment_seed(11, "in_between.1"))]
    other = run(engine, handle, {**edits[0], "seed": 5}, edits[1])
    assert not np.array_equal(other.motion.joints[:20], first.motion.joints[:20])
    assert np.array_equal(other.motion.joints[20:50], first.motion.joints[20:50])   # segment 1 kept in both


@pytest.mark.parametrize("arch", ARCHS)
def test_an_edited_motion_is_edited_again_and_its_recipe_replays_the_chain(engines, originals, arch):
    engine = engines[arch]
    _, _, handle = originals[arch]
    once = run(engine, handle, {"op": "in_between", "after": 0, "text": "a person turns", "duration": 0.5})
    twice = run(engine, once.handle, {"op": "body_part", "segment": 3, "part": "lower_body", "seed": 9})
    chain = recipe_json(twice.handle)["edits"]
    assert [[edit["op"] for edit in step] for step in chain] == [["in_between"], ["body_part"]]
    assert all(edit["seed"] is not None for step in chain for edit in step)
    assert np.array_equal(run(engine, twice.handle).motion.joints, twice.motion.joints)
    assert np.array_equal(twice.motion.joints[:50], once.motion.joints[:50])


@pytest.mark.parametrize(("tamper", "part"), [
    (lambda b: b.update(seed=-1), "handle.seed"),
    (lambda b: b.update(guidance="2"), "handle.guidance"),
    (lambda b: b["segments"][0].update(duration=9.0), "handle.segments.0.duration"),   # MDM: 180 frames > 60
    (lambda b: b["segments"][1].update(duration=None), "handle.segments.1.duration"),
    (lambda b: b["segments"][2].update(text=" x"), "handle.segments.2.text"),
    (lambda b: b["segments"][0].update(frames=3), "handle.segments.0"),
    (lambda b: b.update(extra=1), "handle"),
    (lambda b: b.update(edits=[[{"op": "in_between", "after": 0, "text": "t", "duration": 1.0}]]),
     "handle.edits.0.0.seed"),
    (lambda b: b.update(edits=[[{"op": "in_between", "after": 7, "text": "t", "duration": 1.0, "seed": 1}]]),
     "handle.edits.0.0.after"),
    (lambda b: b.update(edits=[[{"op": "body_part", "segment": 0, "part": "arms", "seed": 1}]]),
     "handle.edits.0.0.part"),
    (lambda b: b.update(edits=[[{"op": "regenerate", "segment": 9, "seed": 1}]]), "handle.edits.0.0.segment"),
    (lambda b: b.update(edits=[[{"op": "append", "segments": [{"text": "t", "duration": None}], "seed": 1}]]),
     "handle.edits.0.0.segments.0.duration"),
    (lambda b: b.update(edits=[[]]), "handle.edits.0"),
    (lambda b: b.update(version="9.9.9"), "handle.model"),
])
def test_a_tampered_recipe_is_refused_naming_the_part(engines, originals, tamper, part):
    engine = engines["mdm"]
    body = recipe_json(originals["mdm"][2])
    tamper(body)
    with pytest.raises(HandleError) as refused:
        run(engine, recipe_of(body))
    assert refused.value.part == part, str(refused.value)


def test_a_flipped_byte_a_token_handle_and_a_long_chain_are_refused(engines, originals):
    engine = engines["dip"]
    handle = originals["dip"][2]
    packed = bytearray(base64.urlsafe_b64decode(handle[5:] + "=" * (-len(handle[5:]) % 4)))
    packed[3] ^= 1
    flipped = RECIPE_PREFIX + base64.urlsafe_b64encode(bytes(packed)).rstrip(b"=").decode()
    with pytest.raises(HandleError, match=r"handle\.checksum"):
        run(engine, flipped)
    with pytest.raises(HandleError, match="t2m2"):
        run(engine, "t2m1." + handle[5:])
    with pytest.raises(HandleError, match=r"handle\.model"):
        read_recipe(handle, replace(engine.limits, name="another"))
    body = recipe_json(handle)
    body["edits"] = [[{"op": "body_part", "segment": 0, "part": "upper_body", "seed": s}]
                     for s in range(MAX_EDIT_STEPS)]
    with pytest.raises(EditError, match="already records"):
        run(engine, recipe_of(body), {"op": "body_part", "segment": 1, "part": "upper_body"})
    body["edits"].append(body["edits"][0])
    with pytest.raises(HandleError, match=r"handle\.edits"):
        run(engine, recipe_of(body))


@pytest.mark.parametrize("arch", ARCHS)
def test_edits_over_http(bundles, make_client, arch):
    client = make_client(Settings(bundle_path=bundles / arch, intra_op_threads=1))
    assert client.get("/health").json()["model"]["extra"]["edits"] == ["append", "body_part", "in_between",
                                                                       "prepend", "regenerate"]
    generated = client.post("/generate", json={"segments": [{"text": t, "duration": d} for t, d in THREE],
                                               "seed": 11}).json()
    handle = generated["handle"]
    assert handle.startswith(RECIPE_PREFIX)
    edits = [{"op": "in_between", "after": 1, "text": "a person turns around", "duration": 1.0, "seed": 2},
             {"op": "body_part", "segment": 0, "part": "upper_body", "end": 0.5}]
    answer = client.post("/edit", json={"handle": handle, "edits": edits})
    assert answer.status_code == 200, answer.text
    edited = answer.json()
    assert edited["edited"] == [{"segment": 0, "seed": segment_seed(11, "body_part.0")},
                                {"segment": 2, "seed": 2}]
    assert [(s["start_frame"], s["end_frame"]) for s in edited["segments"]] == [(0, 20), (20, 50), (50, 70),
                                                                              (70, 83)]
    joints, old = np.asarray(edited["frames"]), np.asarray(generated["frames"])
    assert np.array_equal(joints[20:50], old[20:50]) and not np.array_equal(joints[:20], old[:20])
    again = client.post("/edit", json={"handle": edited["handle"], "edits": []}).json()
    assert again["frames"] == edited["frames"] and again["handle"] == edited["handle"]
    assert client.post("/edit", json={"handle": handle, "edits": edits, "format": "bvh"}).status_code == 200
    refusals = [
        ({"handle": handle, "edits": [{"segment": 3, "seed": 3}]}, ["body", "edits", 0, "segment"]),
        ({"handle": handle, "edits": [{"op": "append", "segments": [{"text": "t", "duration": None}]}]},
         ["body", "edits", 0, "segments", 0, "duration"]),
        ({"handle": handle, "edits": [{"op": "in_between", "after": 2, "text": "t", "duration": 1.0}]},
         ["body", "edits", 0, "after"]),
        ({"handle": handle, "edits": [{"op": "body_part", "segment": 0, "part": "upper_body", "start": 2.0}]},
         ["body", "edits", 0, "start"]),
        ({"handle": handle[:-8] + "AAAAAAAA", "edits": []}, ["body", "handle"]),
    ]
    if arch == "mdm":   # 4 s is 80 frames: more than this MDM's 60
        refusals.append(({"handle": handle, "edits": [{"op": "in_between", "after": 0, "text": "t",
                                                       "duration": 4.0}]}, ["body", "edits", 0, "duration"]))
    for body, loc in refusals:
        refused = client.post("/edit", json=body)
        assert refused.status_code == 422 and refused.json()["detail"][0]["loc"] == loc, (body, refused.text)


def test_another_models_handle_is_refused_at_handle_model(bundles, make_client, originals):
    client = make_client(Settings(bundle_path=bundles / "dip", intra_op_threads=1))
    refused = client.post("/edit", json={"handle": originals["mdm"][2], "edits": []})
    assert refused.status_code == 422 and "handle.model" in refused.json()["detail"][0]["msg"]


def test_t2m_edit_edits_a_saved_diffusion_motion(bundles, tmp_path):
    from t2m.cli.main import main

    model = str(bundles / "dip")
    saved = tmp_path / "walk.json"
    assert main(["generate", "a person walks forward", "--duration", "1", "--then", "a person waves", "--duration",
                 "1.5", "--seed", "5", "--model", model, "-o", str(saved)]) == 0
    original = json.loads(saved.read_text())
    assert original["handle"].startswith(RECIPE_PREFIX)
    edited_path = tmp_path / "edited.json"
    assert main(["edit", str(saved), "--edits", '[{"op": "in_between", "after": 0, "text": "a person turns", '
                 '"duration": 0.5, "seed": 1}]', "--model", model, "-o", str(edited_path)]) == 0
    edited = json.loads(edited_path.read_text())
    assert edited["edited"] == [{"segment": 1, "seed": 1}] and edited["frames"][:20] == original["frames"][:20]
    assert len(edited["frames"]) == len(original["frames"]) + 10


def remade_by_joins(engine, frames: list[int], joins: set[int]) -> np.ndarray:
    """bool per frame of a motion of segments of `frames`: made anew by MDM's in-betweening of these joins."""
    settings = engine.codes.settings
    remade = np.zeros(sum(frames), bool)
    for k, window in numbered_join_windows(frames, settings.join_frames, settings.join_context):
        if k in joins:
            remade[window.start + window.before:window.end - window.after] = True
    return remade


@pytest.mark.parametrize("arch", ARCHS)
def test_regenerate_remakes_the_segment_and_keeps_the_rest(engines, originals, arch):
    engine = engines[arch]
    _, motion, handle = originals[arch]
    answer = run(engine, handle, {"segment": 1, "text": "a person jumps", "seed": 3})
    assert answer.edited == [(1, 3)]
    old, new = np.concatenate(motion.codes), np.concatenate(frames_of(engine, answer.handle))
    allowed = np.zeros(len(old), bool)
    allowed[20:50] = True                                   # the segment; MDM: and its joins' windows
    if arch == "mdm":
        allowed |= remade_by_joins(engine, [20, 30, 13], {0, 1})
    changed = (new != old).any(axis=1)
    assert not changed[~allowed].any() and changed[20:50].mean() > 0.9
    first = int(np.flatnonzero(allowed)[0])
    last = int(np.flatnonzero(allowed)[-1]) + 1
    assert np.array_equal(answer.motion.joints[:first], motion.joints[:first])
    assert_rigidly_moved(answer.motion.joints[last:], motion.joints[last:])
    longer = run(engine, handle, {"segment": 0, "duration": 2.0})
    assert [(s.start_frame, s.end_frame) for s in longer.motion.segments] == [(0, 40), (40, 70), (70, 83)]


@pytest.mark.parametrize("arch", ARCHS)
@pytest.mark.parametrize("op", ["append", "prepend"])
def test_append_and_prepend_keep_the_motion(engines, originals, arch, op):
    engine = engines[arch]
    _, motion, handle = originals[arch]
    added = [{"text": "a person sits down", "duration": 1.0}, {"text": "a person stands up", "duration": 0.8}]
    answer = run(engine, handle, {"op": op, "segments": added, "seed": 6})
    frames = frames_of(engine, answer.handle)
    assert [len(f) for f in frames] == ([20, 30, 13, 20, 16] if op == "append" else [20, 16, 20, 30, 13])
    old = np.concatenate(motion.codes)
    new = np.concatenate(frames[:3] if op == "append" else frames[2:])
    kept = np.ones(len(old), bool)
    if arch == "mdm":   # the join with the new segments is in-betweened
        lengths = [20, 30, 13, 20, 16] if op == "append" else [20, 16, 20, 30, 13]
        remade = remade_by_joins(engine, lengths, {2} if op == "append" else {1})
        kept &= ~(remade[:63] if op == "append" else remade[36:])
    assert np.array_equal(new[kept], old[kept]) and kept.sum() > 50
    assert answer.edited == ([(3, 6), (4, 6)] if op == "append" else [(0, 6), (1, 6)])
    joints = answer.motion.joints
    if op == "append":
        first = int(np.flatnonzero(~kept)[0]) if not kept.all() else 63
        assert np.array_equal(joints[:first], motion.joints[:first])
    else:
        after = int(np.flatnonzero(~kept)[-1]) + 1 if not kept.all() else 0
        assert_rigidly_moved(joints[36 + after:], motion.joints[after:])


def test_an_edit_past_its_time_limit_is_a_504_and_queued_work_past_its_deadline_never_runs(bundles, make_client):
    """Diffusion edits go through the model's batcher as work items: they answer 504 after T2M_REQUEST_TIMEOUT_S,
    and one whose caller timed out while it waited behind other work is never started."""
    import asyncio
    import threading

    from t2m.runtime.scheduling import GenerationTimeout, MicroBatcher

    client = make_client(Settings(bundle_path=bundles / "mdm", intra_op_threads=1, request_timeout_s=1e-4))
    handle = make_client(Settings(bundle_path=bundles / "mdm", intra_op_threads=1)).post(
        "/generate", json={"segments": [{"text": "a person walks", "duration": 1.0}], "seed": 1}).json()["handle"]
    late = client.post("/edit", json={"handle": handle, "edits": [{"op": "append", "segments": [
        {"text": "a person sits down", "duration": 1.0}]}]})
    assert late.status_code == 504 and "T2M_REQUEST_TIMEOUT_S" in late.json()["detail"]

    batcher = MicroBatcher(engine=None, workers=1)  # type: ignore[arg-type]  # work items need no engine
    ran: list[str] = []
    holding, release = threading.Event(), threading.Event()

    def hold() -> str:
        holding.set()
        release.wait(5)
        ran.append("first")
        return "first"

    async def scenario() -> None:
        first = asyncio.ensure_future(batcher.run(hold, 10))
        await asyncio.get_running_loop().run_in_executor(None, holding.wait)
        with pytest.raises(GenerationTimeout):
            await batcher.run(lambda: ran.append("second"), 0.05)   # waits behind `hold`, its caller gives up
        release.set()
        assert await first == "first"
        assert await batcher.run(lambda: "third", 10) == "third"

    asyncio.run(scenario())
    batcher.close()
    assert ran == ["first"]


def test_an_edit_in_flight_is_counted_on_metrics(bundles, make_client, monkeypatch):
    """A diffusion edit is work of the model's batcher: while it runs, /metrics counts it in t2m_in_flight (what
    the queue-depth autoscaler and drain checks read), and the count drops when it is answered."""
    import re
    import threading

    import t2m.families.diffusion.served as diffusion_served

    client = make_client(Settings(bundle_path=bundles / "mdm", intra_op_threads=1))
    name = client.get("/health").json()["default"]
    handle = client.post("/generate", json={"segments": [{"text": "a person walks", "duration": 1.0}],
                                            "seed": 1}).json()["handle"]
    started, release = threading.Event(), threading.Event()
    real_edit = diffusion_served.edit_recipe

    def held_edit(*args):
        started.set()
        release.wait(10)
        return real_edit(*args)

    monkeypatch.setattr(diffusion_served, "edit_recipe", held_edit)

    def in_flight() -> float:
        text = client.get("/metrics").text
        return float(re.search(rf'^t2m_in_flight{{model="{re.escape(name)}"}} (\S+)$', text, re.M).group(1))

    assert in_flight() == 0
    answers: list = []
    body = {"handle": handle, "edits": [{"segment": 0, "text": "a person runs"}]}
    editing = threading.Thread(target=lambda: answers.append(client.post("/edit", json=body)))
    editing.start()
    assert started.wait(10)
    assert in_flight() == 1
    release.set()
    editing.join(20)
    assert answers and answers[0].status_code == 200, answers[0].text
    assert in_flight() == 0
