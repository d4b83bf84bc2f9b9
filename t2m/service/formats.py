"""A Motion in the three answer formats: json (joint positions), BVH (text) and glTF binary.

BVH and glb come from the motion core (motion.bvh_export turns positions into a rotation hierarchy with motion.ik;
motion.gltf writes a skinned-skeleton animation); this module only picks the writer and the HTTP metadata.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from t2m.motion.skeleton import get_skeleton
from t2m.service.engine.types import ModelLimits, Motion

__all__ = ["FILENAMES", "MEDIA_TYPES", "Rendered", "motion_bvh", "motion_glb", "motion_json", "preload", "render"]

MEDIA_TYPES = {"json": "application/json", "bvh": "text/plain; charset=utf-8", "glb": "model/gltf-binary"}
FILENAMES = {"bvh": "motion.bvh", "glb": "motion.glb", "json": "motion.json"}
JSON_DECIMALS = 5   # 10 micrometres: far below any visible difference, keeps the answer compact


@dataclass(frozen=True)
class Rendered:
    body: bytes
    media_type: str
    filename: str


def motion_json(motion: Motion, limits: ModelLimits) -> dict[str, Any]:
    """The json answer (schemas.MotionResponse), built directly as plain data for speed."""
    frames = np.round(np.asarray(motion.joints, dtype=np.float64), JSON_DECIMALS).tolist()
    return {
        "fps": motion.fps,
        "joints": list(limits.joint_names),
        "parents": list(limits.parents),
        "frames": frames,
        "segments": [{"text": s.text, "start_frame": s.start_frame, "end_frame": s.end_frame}
                     for s in motion.segments],
        "seed": motion.seed,
        "model": {"name": limits.name, "version": limits.version},
        "warnings": list(motion.warnings),
    }


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


def render(motion: Motion, fmt: str, limits: ModelLimits) -> Rendered:
    """The motion as bytes in format `fmt` ('json' | 'bvh' | 'glb') with its media type and file name."""
    if fmt == "json":
        import json

        body = json.dumps(motion_json(motion, limits), separators=(",", ":")).encode()
    elif fmt == "bvh":
        body = motion_bvh(motion, limits.skeleton).encode()
    elif fmt == "glb":
        body = motion_glb(motion, limits.skeleton)
    else:
        raise ValueError(f"format: must be json, bvh or glb, got {fmt!r}")
    return Rendered(body=body, media_type=MEDIA_TYPES[fmt], filename=FILENAMES[fmt])
