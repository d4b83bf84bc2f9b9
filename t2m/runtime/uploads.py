"""A motion the user brings to POST /edit (`motion`: JSON joints or a BVH file) turned into the handle of its codes,
so that from then on it is edited exactly as a motion the service made.

The path: joint positions (a BVH file's forward kinematics, centimetres to metres) -> resampled to the model's frame
rate -> HumanML3D's normalisation and features (t2m.motion: the numpy pipeline the training data went through) ->
the bundle's mean/std and encoder.onnx (OnnxEngine.encode) -> codes, split into the upload's segments at whole code
steps. What comes back is the codes' decoding: (frames at the model's rate - 1) // frames_per_token code steps,
re-rooted as every answer is (starting at the origin, facing +Z), not the uploaded frames themselves.

Uploads are untrusted: their sizes are bounded by the schema (and the body limit) before any work, and the frame
count against the API's limits before the features are computed. Every refusal is an EditError naming the field
("body", "motion", ...): a 422.
"""
from __future__ import annotations

import io
import math
from collections.abc import Callable

import numpy as np

from t2m.api import UploadedMotion
from t2m.motion.bvh import BvhError, read_bvh
from t2m.motion.bvh_export import CM_PER_METRE, bvh_joint_names
from t2m.motion.features import joints_to_features, normalize_joints
from t2m.motion.retarget import clean_fps
from t2m.motion.skeleton import get_skeleton
from t2m.motion.transforms import resample
from t2m.runtime.editing import EditError
from t2m.runtime.handles import HandleSegment, MotionHandle
from t2m.runtime.limits import MAX_SEGMENTS, MAX_TOTAL_S, MIN_DURATION_S
from t2m.runtime.types import ModelLimits

__all__ = ["DEFAULT_TEXT", "uploaded_handle"]

DEFAULT_TEXT = "uploaded motion"
JSON_FPS = 20.0                         # an upload's joints without `fps`: the answers' rate
MOTION = ("body", "motion")


Encode = Callable[[np.ndarray], np.ndarray]    # features [frames, D] -> codes [steps, *step shape] (OnnxEngine.encode)


def _check_length(frames: int, fps: float, field: str) -> None:
    """At most the API's total duration (before any work on the frames)."""
    if frames / fps > MAX_TOTAL_S + 1e-9:
        raise EditError((*MOTION, field), f"{frames} frames at {fps:g} fps last {frames / fps:g} s, more than "
                                          f"{MAX_TOTAL_S:g} s")


def _json_joints(motion: UploadedMotion, limits: ModelLimits) -> tuple[np.ndarray, float]:
    assert motion.joints is not None
    fps = JSON_FPS if motion.fps is None else float(motion.fps)
    _check_length(len(motion.joints), fps, "joints")
    count = len(limits.joint_names)
    bad = next((t for t, frame in enumerate(motion.joints) if len(frame) != count), None)
    if bad is not None:
        raise EditError((*MOTION, "joints", bad), f"frame {bad} has {len(motion.joints[bad])} joints; model "
                                                  f"{limits.name!r} ({limits.skeleton}) has {count}")
    joints = np.asarray(motion.joints, dtype=np.float64)
    if not np.all(np.isfinite(joints)):
        raise EditError((*MOTION, "joints"), "holds a value that is not a finite number")
    return joints, fps


def _skeleton_order(names: list[str], parents: list[int], skeleton: str) -> list[int] | None:
    """Index in the file of each of the skeleton's joints (a BVH file lists them depth first), or None when the
    file's joints or their parents are not the skeleton's (by this service's BVH names)."""
    wanted = bvh_joint_names(skeleton)
    if sorted(names) != sorted(wanted) or len(set(names)) != len(names):
        return None
    order = [names.index(name) for name in wanted]
    expected = [-1 if p < 0 else wanted[p] for p in get_skeleton(skeleton).parents]
    found = [-1 if parents[i] < 0 else names[parents[i]] for i in order]
    return order if found == expected else None


def _bvh_joints(text: str, limits: ModelLimits) -> tuple[np.ndarray, float]:
    try:
        bvh = read_bvh(io.StringIO(text))            # a stream: text is never taken for a path
    except (BvhError, ValueError, RecursionError) as error:
        raise EditError((*MOTION, "bvh"), f"not a BVH file this service can read: {error}") from None
    order = _skeleton_order(bvh.joint_names, [int(p) for p in bvh.parents], limits.skeleton)
    if order is None:
        names = bvh_joint_names(limits.skeleton)
        raise EditError((*MOTION, "bvh"), f"its skeleton ({len(bvh.joint_names)} joints: "
                        f"{', '.join(bvh.joint_names[:4])}, ...) is not this service's {limits.skeleton} skeleton "
                        f"({len(names)} joints: {', '.join(names[:4])}, ...: the BVH files its answers are)")
    fps = clean_fps(bvh.fps)
    if not 1.0 <= fps <= 120.0:
        raise EditError((*MOTION, "bvh"), f"frame time {bvh.frame_time:g} s: frame rates of 1-120 fps are read")
    if bvh.num_frames < 2:
        raise EditError((*MOTION, "bvh"), f"{bvh.num_frames} frame(s); a motion needs at least 2")
    _check_length(bvh.num_frames, fps, "bvh")
    return bvh.forward_kinematics()[:, order] / CM_PER_METRE, fps


def _boundaries(motion: UploadedMotion, frames: int, fps: float, steps: int, limits: ModelLimits) -> list[int]:
    """The code step where each segment ends (the last: `steps`), from the segments' frame counts."""
    if motion.segments is None:
        count = math.ceil(steps / limits.max_tokens)
        return [round(steps * (i + 1) / count) for i in range(count)]
    total = sum(s.frames for s in motion.segments)
    if total != frames:
        raise EditError((*MOTION, "segments"), f"the segments cover {total} frames; the upload has {frames}")
    per_step = fps * limits.frames_per_token / limits.fps          # upload frames per code step
    ends, covered = [], 0
    for segment in motion.segments:
        covered += segment.frames
        ends.append(min(steps, round(covered / per_step)))
    ends[-1] = steps
    return ends


def _segments(motion: UploadedMotion, codes: np.ndarray, frames: int, fps: float,
              limits: ModelLimits) -> list[HandleSegment]:
    """The codes split at the segments' boundaries, each segment within the API's and the model's limits."""
    ends = _boundaries(motion, frames, fps, len(codes), limits)
    if len(ends) > MAX_SEGMENTS:
        raise EditError((*MOTION, "segments"), f"{len(ends)} segments of at most {limits.max_segment_seconds:g} s "
                                               f"needed; at most {MAX_SEGMENTS}")
    texts = [DEFAULT_TEXT] * len(ends) if motion.segments is None else [s.text for s in motion.segments]
    out, start = [], 0
    for index, (text, end) in enumerate(zip(texts, ends)):
        steps = end - start
        seconds = steps * limits.frames_per_token / limits.fps
        if steps > limits.max_tokens or seconds < MIN_DURATION_S:
            raise EditError((*MOTION, "segments", index, "frames"), f"segment {index} makes {steps} code steps "
                            f"({seconds:g} s); a segment is {MIN_DURATION_S:g}-{limits.max_segment_seconds:g} s "
                            f"(1-{limits.max_tokens} steps of {limits.frames_per_token / limits.fps:g} s)")
        out.append(HandleSegment(text, seconds, codes[start:end]))
        start = end
    return out


def uploaded_handle(motion: UploadedMotion, limits: ModelLimits, encode: Encode | None) -> MotionHandle:
    """The handle an uploaded motion's codes make for the model of `limits` (its defaults for guidance, temperature
    and top_k; the upload's seed), `encode` its engine's encoder, or an EditError naming the field."""
    if not limits.encodes or encode is None:
        raise EditError(MOTION, f"model {limits.name!r} cannot encode uploaded motions (its bundle has no "
                                "encoder.onnx); edit a handle of its answers instead")
    joints, fps = _bvh_joints(motion.bvh, limits) if motion.bvh is not None else _json_joints(motion, limits)
    frames, source = len(joints), "bvh" if motion.bvh is not None else "joints"
    if fps != limits.fps:
        joints = resample(joints, fps, limits.fps)
    steps = (len(joints) - 1) // limits.frames_per_token       # features are one frame fewer than the joints
    if steps * limits.frames_per_token / limits.fps < MIN_DURATION_S:
        raise EditError((*MOTION, source), f"{frames} frames at {fps:g} fps make {steps} code steps of "
                        f"{limits.frames_per_token} frames at {limits.fps} fps; a motion lasts at least "
                        f"{MIN_DURATION_S:g} s")
    try:
        with np.errstate(all="ignore"):               # degenerate poses are refused below, not warned about
            features = joints_to_features(normalize_joints(joints, limits.skeleton), limits.skeleton)
    except ValueError as error:                     # e.g. a zero-length leg: no reference skeleton to scale to
        raise EditError((*MOTION, source), f"not a pose sequence the features can be made of: {error}") from None
    if not np.all(np.isfinite(features)):             # coincident joints give no bone directions
        raise EditError((*MOTION, source), "its poses are degenerate (coincident joints give no bone directions)")
    codes = encode(features[:steps * limits.frames_per_token])
    return MotionHandle(limits.name, limits.version, motion.seed, limits.guidance(None), 1.0, None,
                        _segments(motion, codes, frames, fps, limits))

