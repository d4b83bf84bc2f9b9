"""A Motion in the three answer formats: json (joint positions), BVH (text) and glTF binary, and the json format's
stream (newline-delimited JSON messages: start, frames..., end, or error once the answer has begun).

BVH and glb come from the motion core (motion.bvh_export turns positions into a rotation hierarchy with motion.ik;
motion.gltf writes a skinned-skeleton animation); this module only picks the writer and the HTTP metadata. A stream's
end message is the json answer without its frames, so its frames messages put together with it give that answer.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

import numpy as np
import orjson

from t2m.motion.skeleton import get_skeleton
from t2m.runtime.types import ModelLimits, Motion

__all__ = ["FILENAMES", "MEDIA_TYPES", "STREAM_MEDIA_TYPE", "Rendered", "frames_json", "motion_bvh", "motion_glb",
           "motion_json", "ndjson", "preload", "render", "stream_end", "stream_error", "stream_frames",
           "stream_start"]

MEDIA_TYPES = {"json": "application/json", "bvh": "text/plain; charset=utf-8", "glb": "model/gltf-binary"}
STREAM_MEDIA_TYPE = "application/x-ndjson"
FILENAMES = {"bvh": "motion.bvh", "glb": "motion.glb", "json": "motion.json"}
JSON_DECIMALS = 5   # 10 micrometres: far below any visible difference, keeps the answer compact


@dataclass(frozen=True)
class Rendered:
    body: bytes
    media_type: str
    filename: str


def _json_bytes(data: dict[str, Any]) -> bytes:
    """Compact JSON by orjson, frames straight from their numpy array: a 10 s motion's 13,200 coordinates took 11 ms
    in json.dumps (the GIL held, the engine's thread waiting) and take about 1 ms, the same numbers byte for byte
    (non-ASCII text is written as UTF-8 instead of \\u escapes). Text orjson refuses (a lone surrogate a client
    sent) goes through json.dumps."""
    try:
        return orjson.dumps(data, option=orjson.OPT_SERIALIZE_NUMPY)
    except orjson.JSONEncodeError:
        return json.dumps(data, separators=(",", ":"), default=_as_list).encode()


def _as_list(value: object) -> list:
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def frames_json(joints: np.ndarray) -> np.ndarray:
    """Joint positions [T, J, 3] rounded to JSON_DECIMALS (the same in a stream as in a whole), as the float64
    array the answer's JSON writes as nested lists (orjson reads it without a Python float per coordinate: the
    lists took 4-17 ms of GIL per 30 s answer)."""
    return np.round(np.asarray(joints, dtype=np.float64), JSON_DECIMALS)


def _playback(fps: int, limits: ModelLimits) -> dict[str, Any]:
    """How to play the frames: the rate, the joint names, the parents."""
    return {"fps": fps, "joints": list(limits.joint_names), "parents": list(limits.parents)}


def _model(limits: ModelLimits) -> dict[str, str]:
    return {"name": limits.name, "version": limits.version}


def _about(motion: Motion, limits: ModelLimits, handle: str | None, extra: dict[str, Any] | None) -> dict[str, Any]:
    """What the frames are: the sentences' spans, the seed, the model, the warnings, the handle (service/handles.py:
    what POST /edit takes back) and what an edit adds."""
    return {"segments": [{"text": s.text, "start_frame": s.start_frame, "end_frame": s.end_frame}
                         for s in motion.segments],
            "seed": motion.seed, "model": _model(limits), "warnings": list(motion.warnings), "handle": handle,
            **(extra or {})}


def motion_json(motion: Motion, limits: ModelLimits, handle: str | None = None,
                extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """The json answer (schemas.MotionResponse, or EditResponse with `extra`), built directly as plain data."""
    return {**_playback(motion.fps, limits), "frames": frames_json(motion.joints),
            **_about(motion, limits, handle, extra)}


def ndjson(message: dict[str, Any]) -> bytes:
    """One line of a stream."""
    return _json_bytes(message) + b"\n"


def stream_start(limits: ModelLimits, seed: int) -> dict[str, Any]:
    """What a player needs before the first frame: the rate, the skeleton, the model and the seed."""
    return {"type": "start", **_playback(limits.fps, limits), "model": _model(limits), "seed": seed}


def stream_frames(start_frame: int, joints: np.ndarray) -> dict[str, Any]:
    """Frames start_frame .. start_frame + len(joints) - 1, final: they never change afterwards."""
    return {"type": "frames", "start_frame": start_frame, "frames": frames_json(joints)}


def stream_end(motion: Motion, limits: ModelLimits, handle: str | None = None) -> dict[str, Any]:
    """The json answer without its frames (sent before it), and how many frames there were."""
    return {"type": "end", **_playback(motion.fps, limits), **_about(motion, limits, handle, None),
            "frame_count": len(motion.joints)}


def stream_error(status: int, detail: str) -> dict[str, Any]:
    """A failure after the answer began (the HTTP status is 200 by then): what the status would have been."""
    return {"type": "error", "status": status, "detail": detail}


def motion_bvh(motion: Motion, skeleton_name: str = "smpl22") -> str:
    """BVH text whose forward kinematics gives the motion's joints back."""
    from t2m.motion.bvh_export import joints_to_bvh

    return joints_to_bvh(motion.joints, get_skeleton(skeleton_name), fps=motion.fps)


def motion_glb(motion: Motion, skeleton_name: str = "smpl22") -> bytes:
    """A binary glTF (skeleton + animation) of the motion."""
    from t2m.motion.gltf import joints_to_glb

    return joints_to_glb(motion.joints, get_skeleton(skeleton_name), motion.fps)


def preload() -> None:
    """Import the BVH and glTF writers now (seconds on a busy machine) rather than in the first request."""
    import t2m.motion.bvh_export
    import t2m.motion.gltf  # noqa: F401


def render(motion: Motion, fmt: str, limits: ModelLimits, handle: str | None = None,
           extra: dict[str, Any] | None = None) -> Rendered:
    """The motion as bytes in format `fmt` ('json' | 'bvh' | 'glb') with its media type and file name; the json
    answer carries `handle` (and `extra`'s fields)."""
    if fmt == "json":
        body = _json_bytes(motion_json(motion, limits, handle, extra))
    elif fmt == "bvh":
        body = motion_bvh(motion, limits.skeleton).encode()
    elif fmt == "glb":
        body = motion_glb(motion, limits.skeleton)
    else:
        raise ValueError(f"format: must be json, bvh or glb, got {fmt!r}")
    return Rendered(body=body, media_type=MEDIA_TYPES[fmt], filename=FILENAMES[fmt])
