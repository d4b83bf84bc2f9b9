"""The committed default model (t2m/bundles/default: T2M-HiFiGPT after 0.4.0) through the engine and the API; skipped
until it is committed."""
from __future__ import annotations

import numpy as np
import pytest

from t2m.runtime.types import GenerationRequest, SegmentRequest


@pytest.fixture(scope="module")
def default_engine(default_model):
    from t2m.runtime.engine import OnnxEngine

    return OnnxEngine.load(default_model)          # verifies every file's sha256


def test_default_bundle_manifest(default_engine):
    limits = default_engine.limits
    assert limits.skeleton == "smpl22" and limits.fps == 20 and limits.frames_per_token == 8
    assert len(limits.joint_names) == 22


def test_default_model_makes_a_plausible_walk(default_engine):
    from t2m.motion.skeleton import SMPL22

    motion = default_engine.generate(GenerationRequest(
        segments=[SegmentRequest("a person walks forward", 3.0), SegmentRequest("a person waves", 2.0)], seed=0,
        guidance=default_engine.limits.default_guidance if default_engine.limits.unconditional_branch else 1.0))
    joints = motion.joints
    # 3 s -> 8 steps of 8 frames fitted to 60, 2 s -> 5 steps, 40 frames: exactly 20 frames a second
    assert joints.shape == (100, 22, 3) and np.isfinite(joints).all()
    assert [(s.start_frame, s.end_frame) for s in motion.segments] == [(0, 60), (60, 100)]
    head, pelvis = joints[:, 15, 1], joints[:, 0, 1]
    assert (head > pelvis + 0.3).all() and 1.2 < head.mean() < 2.0
    feet = joints[:, list(SMPL22.foot_joints), 1]
    assert abs(feet.min()) < 0.1, "the feet are not on the floor"
    walked = np.linalg.norm(joints[59, 0, [0, 2]] - joints[0, 0, [0, 2]])
    assert walked > 0.3, f"the pelvis moved {walked:.2f} m during 'walks forward'"


@pytest.mark.xfail(strict=True, reason="known failure of every default model so far: joints recovered from its "
                   "generated features do not keep one length per bone (max std 2.3-5.1 cm over seeds 0-4 for "
                   "T2M-HiFiGPT 0.3.0, 5.1 for seed 0, this test's; 0.2.1: 3.4-5.0; the GPT model: 3.4-4.4 cm for "
                   "0.3.0, 4.2-4.9 for 0.2.0, whose VQ-VAE's bone-length term keeps its reconstructions within 4 mm). "
                   "The BVH and glb exports are rigid (IK onto the motion's own bone lengths); forcing one length per "
                   "bone on the JSON joints lowered raised wrists and the raise-hand probes, so it is not done.")
def test_default_model_keeps_bone_lengths(default_engine):
    from t2m.motion.skeleton import SMPL22

    motion = default_engine.generate(GenerationRequest(
        segments=[SegmentRequest("a person walks forward", 3.0), SegmentRequest("a person waves", 2.0)], seed=0,
        guidance=default_engine.limits.default_guidance))
    parents = np.asarray(SMPL22.parents[1:])
    bones = np.linalg.norm(motion.joints[:, 1:] - motion.joints[:, parents], axis=-1)
    assert bones.std(axis=0).max() < 0.03, f"bone lengths drift by {bones.std(axis=0).max():.3f} m"


def test_default_model_bvh_round_trip(default_engine):
    from t2m.motion.bvh import read_bvh
    from t2m.motion.bvh_export import bvh_joint_names
    from t2m.motion.skeleton import SMPL22
    from t2m.runtime.formats import motion_bvh

    motion = default_engine.generate(GenerationRequest(segments=[SegmentRequest("a person turns around", 4.0)],
                                                       seed=1, guidance=1.0))
    bvh = read_bvh(motion_bvh(motion))
    order = [bvh.joint_index(name) for name in bvh_joint_names(SMPL22)]
    error = np.linalg.norm(bvh.forward_kinematics()[:, order] / 100.0 - motion.joints, axis=-1).mean()
    assert error < 0.02


def test_default_model_through_the_api(default_model, make_client):
    from t2m.service.settings import Settings

    client = make_client(Settings(bundle_path=default_model))
    assert client.get("/health").json()["status"] == "ok"
    response = client.post("/generate", json={"segments": [{"text": "a person jumps", "duration": 2.0}], "seed": 4})
    assert response.status_code == 200 and len(response.json()["frames"]) == 40
