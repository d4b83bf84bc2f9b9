"""POST /edit with a motion the user brings: JSON joints or a BVH file the service wrote, encoded by the
bundle's encoder.onnx and edited as a handle's codes (tiny random bundles of the three token families, over HTTP).

What is guaranteed: the upload comes back as the decoding of its codes, the codes being encoder.onnx's of the
upload's features (resampled to the model's rate, HumanML3D-normalised, cut to whole code steps); the answer's handle
holds those codes, so the same motion is edited from then on as any handle (an append keeps the frames before the
decoder's reach of the join bit for bit). Every refusal is a 422 naming the field.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from t2m.motion.bvh import read_bvh
from t2m.motion.bvh_export import CM_PER_METRE, bvh_joint_names
from t2m.motion.features import joints_to_features, normalize_joints
from t2m.runtime.engine import OnnxEngine
from t2m.runtime.handles import read_handle
from t2m.runtime.reach import probe_reach
from t2m.service.settings import Settings

WALK = [{"text": "a person walks forward", "duration": 3.0}]
APPEND = [{"op": "append", "segments": [{"text": "a person sits down", "duration": 2.0}], "seed": 3}]


@pytest.fixture(scope="module")
def bundles(random_bundle: Path, hifigpt_bundle: Path, masked_bundle: Path) -> dict[str, Path]:
    return {"gpt": random_bundle, "hifigpt": hifigpt_bundle, "masked": masked_bundle}


@pytest.fixture(scope="module")
def engines(bundles: dict[str, Path]) -> dict[str, OnnxEngine]:
    return {family: OnnxEngine.load(path, intra_op_threads=1) for family, path in bundles.items()}


@pytest.fixture(scope="module")
def client(bundles: dict[str, Path]):
    from fastapi.testclient import TestClient

    from t2m.service.app import create_app
    from tests.service.conftest import wait_ready

    settings = Settings(bundle_path=bundles["gpt"], extra_model_dirs=[bundles["hifigpt"], bundles["masked"]],
                        intra_op_threads=1, max_body_bytes=4 << 20)
    with TestClient(create_app(settings)) as test_client:
        wait_ready(test_client)
        yield test_client


@pytest.fixture(scope="module")
def source(client) -> dict:
    """A motion the service made (3 s, 60 frames at 20 fps), as json and as BVH."""
    answer = client.post("/generate", json={"segments": WALK, "seed": 11})
    bvh = client.post("/generate", json={"segments": WALK, "seed": 11, "format": "bvh"})
    assert answer.status_code == 200 and bvh.status_code == 200
    return {"frames": answer.json()["frames"], "bvh": bvh.text}


def post(client, body: dict, status: int = 200):
    response = client.post("/edit", json=body)
    assert response.status_code == status, response.text[:800]
    return response.json()


def kept_prefix(engine: OnnxEngine, kept: dict) -> int:
    """Frames at the start of `kept` that an append must keep bit for bit (docs/api.md's rule): before the decoder's
    reach of the first new code step, and before the last kept segment (whose time map a segment after it moves)."""
    shape = engine.limits.codes.shape
    reach = probe_reach(lambda codes: engine.decoder.decode(codes.reshape(len(codes), *shape)),
                        engine.limits.codebook_size, engine.limits.frames_per_token, depth=int(np.prod(shape)))
    assert reach is not None
    steps = len(kept["frames"]) // engine.limits.frames_per_token
    return min((steps - reach.ahead) * engine.limits.frames_per_token, kept["segments"][-1]["start_frame"])


def expected_codes(engine: OnnxEngine, joints: np.ndarray) -> np.ndarray:
    """The upload's codes as the issue defines them: features of the normalised joints, whole code steps, encoded."""
    features = joints_to_features(normalize_joints(joints))
    per = engine.limits.frames_per_token
    return engine.encode(features[:len(features) // per * per])


@pytest.mark.parametrize("family", ["gpt", "hifigpt", "masked"])
def test_an_uploaded_json_motion_is_its_codes_decoded_and_edits_like_a_handle(family, client, engines, source):
    engine = engines[family]
    name = engine.limits.name
    upload = {"joints": source["frames"], "segments": [{"text": "a person walks forward", "frames": 30},
                                                       {"text": "a person keeps walking", "frames": 30}]}
    kept = post(client, {"motion": upload, "model": name})
    segments = read_handle(kept["handle"], engine.limits).segments
    assert [s.text for s in segments] == ["a person walks forward", "a person keeps walking"]
    codes = np.concatenate([s.codes for s in segments])
    assert np.array_equal(codes, expected_codes(engine, np.asarray(source["frames"])))
    assert len(kept["frames"]) == len(codes) * engine.limits.frames_per_token
    again = post(client, {"handle": kept["handle"]})      # the upload's frames are its codes' decoding, bit for bit
    assert again["frames"] == kept["frames"]

    appended = post(client, {"motion": upload, "model": name, "edits": APPEND})
    keep = kept_prefix(engine, kept)
    assert keep > 0 and appended["frames"][:keep] == kept["frames"][:keep]
    assert len(appended["frames"]) > len(kept["frames"])
    assert [s["text"] for s in appended["segments"]][2:] == ["a person sits down"]
    assert appended["edited"] == [{"segment": 2, "seed": 3}]
    assert post(client, {"motion": upload, "model": name, "edits": APPEND}) == appended     # deterministic
    by_handle = post(client, {"handle": kept["handle"], "edits": APPEND})
    assert by_handle["frames"] == appended["frames"]      # an upload edits exactly as its handle


def test_an_uploaded_bvh_the_service_wrote_is_encoded_and_appended(client, engines, source):
    engine = engines["gpt"]
    kept = post(client, {"motion": {"bvh": source["bvh"], "seed": 4}})
    handle = read_handle(kept["handle"], engine.limits)
    bvh = read_bvh(source["bvh"])
    order = [bvh.joint_names.index(name) for name in bvh_joint_names()]
    joints = bvh.forward_kinematics()[:, order] / CM_PER_METRE
    assert [s.text for s in handle.segments] == ["uploaded motion"] and handle.seed == 4
    assert np.array_equal(handle.segments[0].codes, expected_codes(engine, joints))
    upload = {"bvh": source["bvh"], "segments": [{"text": "a person walks", "frames": 20},
                                                 {"text": "a person walks on", "frames": 40}]}
    kept = post(client, {"motion": upload})
    appended = post(client, {"motion": upload, "edits": APPEND, "format": "json"})
    keep = kept_prefix(engine, kept)
    assert keep > 0 and appended["frames"][:keep] == kept["frames"][:keep]
    assert post(client, {"motion": upload, "edits": APPEND}) == appended
    as_bvh = client.post("/edit", json={"motion": upload, "edits": APPEND, "format": "bvh"})
    assert as_bvh.status_code == 200 and as_bvh.text.startswith("HIERARCHY")


def test_a_long_upload_without_segments_is_split_within_the_models_segments(client, engines):
    long = client.post("/generate", json={"segments": [{"text": "a person walks", "duration": 6.0},
                                                       {"text": "a person runs", "duration": 6.0}], "seed": 2})
    frames = long.json()["frames"]
    answer = post(client, {"motion": {"joints": frames, "fps": 20}})
    spans = answer["segments"]
    assert [s["text"] for s in spans] == ["uploaded motion"] * 2
    steps = [len(s.codes) for s in read_handle(answer["handle"], engines["gpt"].limits).segments]
    assert max(steps) <= engines["gpt"].limits.max_tokens and abs(steps[0] - steps[1]) <= 1


def test_a_30_fps_upload_is_resampled(client, engines, source):
    from t2m.motion.transforms import resample

    at_30 = resample(np.asarray(source["frames"]), 20.0, 30.0)
    answer = post(client, {"motion": {"joints": np.round(at_30, 5).tolist(), "fps": 30}})
    steps = sum(len(s.codes) for s in read_handle(answer["handle"], engines["gpt"].limits).segments)
    assert steps == (len(source["frames"]) - 1) // engines["gpt"].limits.frames_per_token


def bvh_with(source: dict, old: str, new: str) -> str:
    return source["bvh"].replace(old, new, 1)


REFUSALS = [
    (lambda s: {"joints": [[[0.0, 0.0, 0.0]] * 21] * 30}, ["body", "motion", "joints", 0], "21 joints"),
    (lambda s: {"joints": [[[0.0, 0.0]] * 22] * 30}, ["body", "motion", "joints", 0, 0], ""),
    (lambda s: {"joints": [[[0.0, 0.0, 0.0]] * 22]}, ["body", "motion", "joints"], ""),
    (lambda s: {"joints": [[[0.0, 0.0, 0.0]] * 22] * 30}, ["body", "motion", "joints"], "pose"),
    (lambda s: {"joints": s["frames"][:10]}, ["body", "motion", "joints"], "at least 0.5 s"),
    (lambda s: {"joints": [[[0.0, 0.0, 0.0]] * 22] * 121, "fps": 1}, ["body", "motion", "joints"], "120"),
    (lambda s: {"joints": s["frames"], "segments": [{"text": "a", "frames": 59}]}, ["body", "motion", "segments"],
     "59 frames"),
    (lambda s: {"joints": s["frames"], "segments": [{"text": "a", "frames": 4}, {"text": "b", "frames": 56}]},
     ["body", "motion", "segments", 0, "frames"], "segment 0"),
    (lambda s: {"bvh": "HIERARCHY\nROOT Hips\n{\n"}, ["body", "motion", "bvh"], "BVH"),
    (lambda s: {"bvh": "/etc/passwd"}, ["body", "motion", "bvh"], "BVH"),
    (lambda s: {"bvh": bvh_with(s, "LeftUpLeg", "LeftThigh")}, ["body", "motion", "bvh"], "skeleton"),
    (lambda s: {"bvh": s["bvh"], "fps": 20}, ["body", "motion"], "fps"),
    (lambda s: {"joints": s["frames"], "bvh": s["bvh"]}, ["body", "motion"], "exactly one"),
    (lambda s: {}, ["body", "motion"], "exactly one"),
]


@pytest.mark.parametrize("make, loc, words", REFUSALS)
def test_bad_uploads_are_422_naming_the_field(client, source, make, loc, words):
    detail = post(client, {"motion": make(source)}, status=422)["detail"]
    assert detail[0]["loc"] == loc, detail
    assert words in detail[0]["msg"], detail


def test_non_finite_joints_and_both_a_handle_and_a_motion_are_422(client, source):
    frames = [[list(joint) for joint in frame] for frame in source["frames"]]
    frames[5][3][1] = float("nan")
    bad = json.dumps({"motion": {"joints": frames}})            # Python writes NaN, as a careless client might
    response = client.post("/edit", content=bad, headers={"content-type": "application/json"})
    assert response.status_code == 422
    assert response.json()["detail"][0]["loc"] == ["body", "motion", "joints", 5, 3, 1]
    kept = post(client, {"motion": {"joints": source["frames"]}})
    detail = post(client, {"motion": {"joints": source["frames"]}, "handle": kept["handle"]}, status=422)["detail"]
    assert detail[0]["loc"] == ["body"] and "exactly one" in detail[0]["msg"]


def test_a_model_without_an_encoder_refuses_uploads(make_client, default_model, source):
    client = make_client(Settings(bundle_path=default_model, intra_op_threads=1, max_body_bytes=4 << 20))
    detail = post(client, {"motion": {"joints": source["frames"]}}, status=422)["detail"]
    assert detail[0]["loc"] == ["body", "motion"] and "cannot encode uploaded motions" in detail[0]["msg"]
    assert client.get("/health").json()["model"]["extra"]["uploads"] is False


def test_health_and_openapi_say_who_takes_uploads(client):
    models = client.get("/health").json()["models"]
    assert all(model["extra"]["uploads"] for model in models)
    schema = client.get("/openapi.json").json()["components"]["schemas"]
    assert {"joints", "fps", "bvh", "segments", "seed"} <= set(schema["UploadedMotion"]["properties"])
    assert "motion" in schema["EditRequest"]["properties"]


def test_t2m_edit_uploads_a_saved_json_motion_without_a_handle_and_a_bvh_file(random_bundle, tmp_path, capsys):
    from t2m.cli.main import main

    saved, bvh = tmp_path / "walk.json", tmp_path / "walk.bvh"
    for path in (saved, bvh):
        assert main(["generate", "a person walks forward", "--duration", "2", "--then", "a person waves",
                     "--duration", "2", "--seed", "5", "--model", str(random_bundle), "-o", str(path)]) == 0
    original = json.loads(saved.read_text())
    saved.write_text(json.dumps({key: value for key, value in original.items() if key != "handle"}))
    append = '[{"op": "append", "segments": [{"text": "a person sits", "duration": 2}], "seed": 1}]'
    out = tmp_path / "edited.json"
    assert main(["edit", str(saved), "--edits", append, "--model", str(random_bundle), "-o", str(out)]) == 0
    edited = json.loads(out.read_text())
    assert [s["text"] for s in edited["segments"]] == ["a person walks forward", "a person waves", "a person sits"]
    assert edited["edited"] == [{"segment": 2, "seed": 1}]
    from_bvh = tmp_path / "from_bvh.json"
    assert main(["edit", str(bvh), "--edits", append, "--model", str(random_bundle), "-o", str(from_bvh)]) == 0
    assert [s["text"] for s in json.loads(from_bvh.read_text())["segments"]] == ["uploaded motion", "a person sits"]
    capsys.readouterr()
    (tmp_path / "bad.bvh").write_text("HIERARCHY\nnot a file\n")
    assert main(["edit", str(tmp_path / "bad.bvh"), "--model", str(random_bundle), "-o", str(out)]) == 2
    assert "motion.bvh: not a BVH file" in capsys.readouterr().err


def test_the_sdk_edits_an_upload(live_server):
    from t2m.client import Append, T2MClient, Upload, ValidationError

    with T2MClient(live_server.url, api_key="test-key") as t2m:
        motion = t2m.generate([("a person walks forward", 2.0)], seed=5)
        upload = Upload.of_motion(motion)
        edited = t2m.edit(upload, [Append([("a person sits down", 2.0)], seed=4)])
        assert [s.text for s in edited.segments] == ["a person walks forward", "a person sits down"]
        assert edited.handle and edited.edited == [(1, 4)]
        assert np.array_equal(t2m.edit(upload, [Append([("a person sits down", 2.0)], seed=4)]).frames, edited.frames)
        bvh = t2m.edit_raw(motion, [], "bvh").content.decode()
        assert t2m.edit(Upload(bvh=bvh, seed=2)).segments[0].text == "uploaded motion"
        with pytest.raises(ValidationError) as caught:
            t2m.edit(Upload(joints=motion.frames[:, :21]))
        assert caught.value.fields == ["motion.joints.0"]


def test_the_masked_family_inpaints_an_upload(client, engines, source):
    """The kinds only an inpainting family makes work on an upload's codes as on a handle's: the kept codes stay."""
    engine = engines["masked"]
    upload = {"joints": source["frames"], "segments": [{"text": "a person walks", "frames": 30},
                                                       {"text": "a person keeps walking", "frames": 30}]}
    kept = read_handle(post(client, {"motion": upload, "model": engine.limits.name})["handle"], engine.limits)
    edits = [{"op": "in_between", "after": 0, "text": "a person turns around", "duration": 1.2, "seed": 2},
             {"op": "body_part", "segment": 1, "part": "upper_body", "text": "a person waves", "seed": 3}]
    answer = post(client, {"motion": upload, "model": engine.limits.name, "edits": edits})
    segments = read_handle(answer["handle"], engine.limits).segments
    assert [s.text for s in segments] == ["a person walks", "a person turns around", "a person waves"]
    assert np.array_equal(segments[0].codes, kept.segments[0].codes)
    columns = list(engine.limits.body_parts["upper_body"])
    others = [c for c in range(segments[2].codes.shape[1]) if c not in columns]
    assert np.array_equal(segments[2].codes[:, others], kept.segments[1].codes[:, others])
