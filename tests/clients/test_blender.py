"""Blender (headless) imports our BVH and glb, and its animated armature's joints are ours.

Blender is Z up: its importers turn our Y-up files into (x, -z, y) world coordinates, which the test undoes. The
BVH is in centimetres and imported with scale 0.01; glTF is metres already. The dump script records the imported
action's first frame (BVH: frame 1, glTF: frame 0) so frame k of the file is compared with our frame k.
"""
from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from t2m.motion.bvh_export import bvh_joint_names, joints_to_bvh
from t2m.motion.gltf import joints_to_glb

pytestmark = pytest.mark.clients

DUMP_SCRIPT = Path(__file__).with_name("blender_dump_joints.py")


def blender_joints(kind: str, path: Path, fps: int = 20) -> tuple[np.ndarray, dict]:
    """Animated bone heads [T, 22, 3] in our axes (Y up, metres), SMPL order, as Blender evaluates them."""
    blender = shutil.which("blender")
    if blender is None:
        pytest.skip("blender is not installed (apt-get install blender; scripts/install_clients.sh)")
    output = path.with_suffix(".json")
    result = subprocess.run([blender, "-b", "--factory-startup", "--python", str(DUMP_SCRIPT), "--",
                             kind, str(path), str(output), str(fps)], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0 and output.is_file(), result.stdout[-3000:] + result.stderr[-3000:]
    dump = json.loads(output.read_text())
    heads = np.array([dump["bones"][name] for name in bvh_joint_names()]).transpose(1, 0, 2)  # [T, 22, 3]
    return np.stack([heads[..., 0], heads[..., 2], -heads[..., 1]], axis=-1), dump


@pytest.mark.parametrize("clip", ["turn", "mirrored_backwards"])
def test_blender_bvh_import_reproduces_our_joints(motions, tmp_path, clip):
    joints = motions[clip]
    path = tmp_path / f"{clip}.bvh"
    path.write_text(joints_to_bvh(joints, fps=20))
    theirs, dump = blender_joints("bvh", path)
    assert dump["scene_fps"] == 20 and len(dump["frames"]) == len(joints)
    error = np.linalg.norm(theirs - joints, axis=-1)
    assert error.mean() < 1e-4 and error.max() < 1e-3, f"mean {error.mean():.2e} m, max {error.max():.2e} m"


@pytest.mark.parametrize("clip", ["turn", "mirrored_backwards"])
def test_blender_gltf_import_reproduces_our_joints(motions, tmp_path, clip):
    joints = motions[clip]
    path = tmp_path / f"{clip}.glb"
    path.write_bytes(joints_to_glb(joints, fps=20, body=True))
    theirs, dump = blender_joints("glb", path)
    assert len(dump["frames"]) == len(joints)
    (body,) = dump["meshes"]  # the skinned body came in as a mesh deformed by the armature
    assert body["bound_to_armature"] and body["vertex_groups"] == 22 and body["vertices"] > 1000
    error = np.linalg.norm(theirs - joints, axis=-1)
    assert error.mean() < 1e-4 and error.max() < 1e-3, f"mean {error.mean():.2e} m, max {error.max():.2e} m"
