"""Tiny synthetic CMU-like trials written by the tests: a CC-rig-like BVH (with a T-pose frame 0) and DeepMimic
humanoid3d frames, plus an index.json with timed sentences. Synthetic motion: a body gliding forward at 1 m/s,
legs and knees swinging; nothing here is real capture."""
from __future__ import annotations

import json
import math
from pathlib import Path

from t2m.motion.deepmimic import HUMANOID3D

# (name, parent, offset in cm): the CC_RIG joints (and the rig's root) at their places on a ~1.7 m body facing +z
CC_JOINTS: list[tuple[str, str | None, tuple[float, float, float]]] = [
    ("RL_BoneRoot", None, (0, 0, 0)), ("CC_Base_Hip", "RL_BoneRoot", (0, 100, 0)),
    ("CC_Base_Pelvis", "CC_Base_Hip", (0, 0, 0)),
    ("CC_Base_L_Thigh", "CC_Base_Pelvis", (9, -3, 0)), ("CC_Base_L_Calf", "CC_Base_L_Thigh", (0, -42, 0)),
    ("CC_Base_L_Foot", "CC_Base_L_Calf", (0, -40, 0)), ("CC_Base_L_ToeBase", "CC_Base_L_Foot", (0, -8, 13)),
    ("CC_Base_R_Thigh", "CC_Base_Pelvis", (-9, -3, 0)), ("CC_Base_R_Calf", "CC_Base_R_Thigh", (0, -42, 0)),
    ("CC_Base_R_Foot", "CC_Base_R_Calf", (0, -40, 0)), ("CC_Base_R_ToeBase", "CC_Base_R_Foot", (0, -8, 13)),
    ("CC_Base_Waist", "CC_Base_Hip", (0, 8, 0)), ("CC_Base_Spine01", "CC_Base_Waist", (0, 4, 0)),
    ("CC_Base_Spine02", "CC_Base_Spine01", (0, 15, 0)), ("CC_Base_NeckTwist01", "CC_Base_Spine02", (0, 27, 0)),
    ("CC_Base_Head", "CC_Base_NeckTwist01", (0, 8, 0)),
    ("CC_Base_L_Clavicle", "CC_Base_Spine02", (3, 21, 0)), ("CC_Base_L_Upperarm", "CC_Base_L_Clavicle", (13, 1, 0)),
    ("CC_Base_L_Forearm", "CC_Base_L_Upperarm", (27, 0, 0)), ("CC_Base_L_Hand", "CC_Base_L_Forearm", (25, 0, 0)),
    ("CC_Base_R_Clavicle", "CC_Base_Spine02", (-3, 21, 0)), ("CC_Base_R_Upperarm", "CC_Base_R_Clavicle", (-13, 1, 0)),
    ("CC_Base_R_Forearm", "CC_Base_R_Upperarm", (-27, 0, 0)), ("CC_Base_R_Hand", "CC_Base_R_Forearm", (-25, 0, 0)),
]
TPOSE_ROOT_X_CM = 250.0


def _hierarchy() -> list[str]:
    children: dict[str | None, list[str]] = {}
    offsets = {}
    for name, parent, offset in CC_JOINTS:
        children.setdefault(parent, []).append(name)
        offsets[name] = offset

    def emit(name: str, depth: int) -> list[str]:
        pad = "  " * depth
        root = depth == 0
        lines = [f"{pad}{'ROOT' if root else 'JOINT'} {name}", f"{pad}{{",
                 f"{pad}  OFFSET {' '.join(f'{v:.4f}' for v in offsets[name])}",
                 f"{pad}  CHANNELS {'6 Xposition Yposition Zposition' if root else '3'} Zrotation Yrotation Xrotation"]
        for child in children.get(name, []):
            lines += emit(child, depth + 1)
        if not children.get(name):
            lines += [f"{pad}  End Site", f"{pad}  {{", f"{pad}    OFFSET 0 5 0", f"{pad}  }}"]
        return lines + [f"{pad}}}"]

    return ["HIERARCHY", *emit("RL_BoneRoot", 0)]


def cc_bvh_text(motion_frames: int, fps: float = 60.0, tpose: bool = True) -> str:
    """A CC-rig-like BVH: (a T-pose frame far off at x = 2.5 m, then) the body gliding +z, arms down, legs swinging."""
    names = [name for name, _, _ in CC_JOINTS]
    rows = []
    if tpose:
        rows.append([TPOSE_ROOT_X_CM, 0.0, 0.0] + [0.0] * 3 * len(names))
    for k in range(motion_frames):
        t = k / fps
        values = {name: [0.0, 0.0, 0.0] for name in names}   # Z, Y, X rotations (degrees)
        values["CC_Base_L_Upperarm"][0] = -75.0
        values["CC_Base_R_Upperarm"][0] = 75.0
        values["CC_Base_L_Thigh"][2] = 20.0 * math.sin(2 * math.pi * t)
        values["CC_Base_R_Thigh"][2] = -20.0 * math.sin(2 * math.pi * t)
        rows.append([0.0, 0.0, 100.0 * t] + [v for name in names for v in values[name]])
    motion = ["MOTION", f"Frames: {len(rows)}", f"Frame Time: {1.0 / fps:.6f}"]
    return "\n".join(_hierarchy() + motion + [" ".join(f"{v:.5f}" for v in row) for row in rows]) + "\n"


def deepmimic_frames(count: int, fps: float = 30.0) -> list[list[float]]:
    """humanoid3d frames: root gliding +x (the humanoid's forward) at 1 m/s, hips and knees swinging."""
    frames = []
    for k in range(count):
        t = k / fps
        frame = [1.0 / fps if k < count - 1 else 0.0, t, 0.9, 0.0, 1.0, 0.0, 0.0, 0.0]
        for name, kind in zip(HUMANOID3D.names[1:], HUMANOID3D.types[1:]):
            if kind == "spherical":
                side = 1 if name == "left_hip" else -1 if name == "right_hip" else 0
                swing = 0.2 * math.sin(2 * math.pi * t) * side
                frame += [math.cos(swing / 2), 0.0, 0.0, math.sin(swing / 2)]
            elif kind == "revolute":
                frame.append(-0.3 * (1 + math.sin(2 * math.pi * t)) if "knee" in name else 0.3)
        frames.append(frame)
    return frames


def write_deepmimic(path: Path, frames: list[list[float]]) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"Loop": "none", "Frames": frames}), encoding="utf-8")
    return path


SENTENCES = {7: ["a person walks forward and raises the left hand", "someone walks ahead"],
             8: ["a person walks forward", "walking in a straight line", "the person strolls"],
             9: ["a figure glides forward"]}
INDEX = {
    "01_01": {"files": ["cc-rig-bvh/01_01.bvh", "deepmimic/01_01.txt"], "cmu": {"description": "walk", "fps": 120},
              "humanml3d": [{"humanml3d_id": 7, "split": "train", "start_s": 0.5, "end_s": 1.7,
                             "sentences": SENTENCES[7]},
                            {"humanml3d_id": 8, "split": "test", "start_s": 0.0, "end_s": 2.4,
                             "sentences": SENTENCES[8]}]},
    "02_02": {"files": ["deepmimic/02_02.txt"], "cmu": {"description": "glide", "fps": 120},
              "humanml3d": [{"humanml3d_id": 9, "split": "train", "start_s": 0.2, "end_s": 1.8,
                             "sentences": SENTENCES[9]}]},
    "03_03": {"files": ["deepmimic/03_03.txt"], "cmu": {"description": "no sentences", "fps": 120}, "humanml3d": []},
}


def write_cmu_tree(base: Path) -> Path:
    """base/cmu-captioned/{cc-rig-bvh,deepmimic}/... and base/index.json; returns base/cmu-captioned."""
    root = base / "cmu-captioned"
    (root / "cc-rig-bvh").mkdir(parents=True)
    (root / "cc-rig-bvh" / "01_01.bvh").write_text(cc_bvh_text(150), encoding="utf-8")
    write_deepmimic(root / "deepmimic" / "01_01.txt", deepmimic_frames(75))
    write_deepmimic(root / "deepmimic" / "02_02.txt", deepmimic_frames(60))
    write_deepmimic(root / "deepmimic" / "03_03.txt", deepmimic_frames(10))
    (base / "index.json").write_text(json.dumps(INDEX, indent=1), encoding="utf-8")
    return root
