"""scripts/image_requirements.py: what the image (Dockerfile) and the offline wheelhouse install; with the `gpu` extra
onnxruntime-gpu replaces the CPU onnxruntime (both install the same module)."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

tomllib = pytest.importorskip("tomllib", reason="Python 3.11+ (the image's script reads pyproject.toml with it)")

REPO = Path(__file__).resolve().parents[2]


def _requirements(extras: list[str], build_system: bool = False) -> list[str]:
    spec = importlib.util.spec_from_file_location("image_requirements", REPO / "scripts" / "image_requirements.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    pyproject = tomllib.loads((REPO / "pyproject.toml").read_text())
    return module.requirements(pyproject, extras, build_system)


def test_cpu_image_installs_onnxruntime_and_no_gpu_build():
    names = _requirements([])
    assert any(r.startswith("onnxruntime>") for r in names) and not any("onnxruntime-gpu" in r for r in names)


def test_gpu_image_installs_onnxruntime_gpu_instead_of_onnxruntime():
    names = _requirements(["gpu"], build_system=True)
    assert [r for r in names if r.startswith("onnxruntime")] == ["onnxruntime-gpu>=1.20"]
    assert any(r.startswith("setuptools") for r in names) and any(r.startswith("fastapi") for r in names)


def test_dockerfile_and_wheelhouse_use_the_script():
    assert "scripts/image_requirements.py pyproject.toml \"$EXTRAS\"" in (REPO / "Dockerfile").read_text()
    assert "image_requirements.py" in (REPO / "scripts" / "build_wheelhouse.sh").read_text()
