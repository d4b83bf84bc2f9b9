"""The Khronos glTF validator (npm `gltf-validator`, pinned in tools/gltf-validator) accepts our glb files."""
from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest

from t2m.motion.gltf import joints_to_glb

pytestmark = pytest.mark.clients

VALIDATOR_DIR = Path(__file__).resolve().parents[2] / "tools" / "gltf-validator"
# Infos the validator emits that are part of the design: without a body mesh, leaf joints are empty nodes.
EXPECTED_INFOS = {"NODE_EMPTY"}


def validate(path) -> dict:
    node = shutil.which("node")
    if node is None:
        pytest.skip("node is not installed (scripts/install_clients.sh)")
    if not (VALIDATOR_DIR / "node_modules" / "gltf-validator").is_dir():
        pytest.skip(f"gltf-validator is not installed in {VALIDATOR_DIR} (run `npm ci` there or "
                    "scripts/install_clients.sh)")
    result = subprocess.run([node, str(VALIDATOR_DIR / "validate.js"), str(path)], capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


@pytest.mark.parametrize("clip,body", [("turn", True), ("mirrored_backwards", True), ("turn", False)])
def test_validator_reports_no_errors_or_warnings(motions, tmp_path, clip, body):
    path = tmp_path / f"{clip}.glb"
    path.write_bytes(joints_to_glb(motions[clip], fps=20, body=body))
    report = validate(path)
    issues = report["issues"]
    messages = [f"{m['code']} {m.get('pointer', '')}: {m['message']}" for m in issues["messages"]]
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, messages
    assert {m["code"] for m in issues["messages"]} <= EXPECTED_INFOS, messages
    info = report["info"]
    assert info["animationCount"] == 1 and info["hasSkins"] == body


def test_validator_catches_a_broken_file(motions, tmp_path):
    """The harness itself can fail: a glb whose buffer is cut short must be reported as an error."""
    glb = bytearray(joints_to_glb(motions["turn"][:5], body=False))
    path = tmp_path / "broken.glb"
    path.write_bytes(bytes(glb[: len(glb) - 64]))
    assert validate(path)["issues"]["numErrors"] > 0
