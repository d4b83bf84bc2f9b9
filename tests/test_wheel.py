"""What a new user meets: the wheel, installed into a fresh virtualenv, run from an unrelated directory.

The wheel is built from a copy of the sources (no build files land in the repository) without build isolation (no
network in tests). The fresh venv gets the wheel with `pip install --no-deps`; its third-party dependencies come from
this test environment's site-packages through a plain path line (a .pth path is not processed for further .pth
files, so this environment's editable install of the repository stays invisible there). What is checked: the `t2m`
script, `--version`, the embedded default model served by `t2m serve` and used by `t2m generate`, and that the
project installs nothing but the `t2m` package (a bare `model`, `service`, `cli` ... import fails).
"""
from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import sysconfig
import time
import urllib.request
import zipfile
from pathlib import Path

import pytest

import t2m

REPO = Path(__file__).resolve().parents[1]


def _clean_env() -> dict[str, str]:
    """This environment minus anything that would let the fresh venv see the repository (PYTHONPATH)."""
    return {**{k: v for k, v in os.environ.items() if k != "PYTHONPATH"}, "PYTHONNOUSERSITE": "1"}


def _run(*command: str | Path, cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    result = subprocess.run([str(part) for part in command], cwd=cwd, capture_output=True, text=True,
                            timeout=timeout, env=_clean_env())
    assert result.returncode == 0, f"{command}: {result.stderr[-3000:]}"
    return result


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    """(venv bin directory, a working directory outside the repository, the wheel)."""
    source = tmp_path_factory.mktemp("source")
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(REPO / name, source / name)
    shutil.copytree(REPO / "t2m", source / "t2m", ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    wheels = tmp_path_factory.mktemp("wheels")
    _run(sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--quiet", "-w", wheels, source,
         cwd=source)
    (wheel,) = wheels.glob("t2m_service-*.whl")
    venv = tmp_path_factory.mktemp("venv") / "fresh"
    _run(sys.executable, "-m", "venv", "--without-pip", venv, cwd=wheels)
    python = venv / "bin" / "python"
    _run(sys.executable, "-m", "pip", "--python", python, "install", "--no-deps", "--no-index", "--quiet", wheel,
         cwd=wheels)
    site = Path(_run(python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])",
                     cwd=wheels).stdout.strip())
    (site / "test_dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    return venv / "bin", tmp_path_factory.mktemp("elsewhere"), wheel


def test_wheel_holds_one_package_the_viewer_and_the_default_model(installed):
    wheel = installed[2]
    names = zipfile.ZipFile(wheel).namelist()
    assert {name.split("/")[0] for name in names} == {"t2m", wheel.name.split("-py3")[0] + ".dist-info"}
    for bundle in ("default", "gpt", "masked"):
        manifest = json.loads((REPO / "t2m" / "bundles" / bundle / "manifest.json").read_text())
        assert {f"t2m/bundles/{bundle}/{name}" for name in [*manifest["files"], "manifest.json"]} <= set(names)
    assert {"t2m/service/static/index.html", "t2m/service/static/viewer.css", "t2m/service/static/viewer/main.js",
            "t2m/runtime/keep_rows.onnx"} <= set(names)
    viewer = {name.rsplit("/", 1)[1] for name in names if name.startswith("t2m/service/static/viewer/")}
    assert viewer == {path.name for path in (REPO / "t2m" / "service" / "static" / "viewer").glob("*.js")}


def test_version_and_single_namespace(installed):
    bin_dir, elsewhere, _ = installed
    assert _run(bin_dir / "t2m", "--version", cwd=elsewhere).stdout.strip() == f"t2m-service {t2m.__version__}"
    probe = ("import importlib.util, t2m; print(t2m.__file__); "
             "print([n for n in ('model', 'service', 'cli', 'client', 'export', 'motion', 'models') "
             "if importlib.util.find_spec(n)])")
    location, bare = _run(bin_dir / "python", "-c", probe, cwd=elsewhere).stdout.strip().splitlines()
    assert str(REPO) not in location and "site-packages" in location
    assert bare == "[]"


def test_generate_from_anywhere_with_the_embedded_model(installed):
    bin_dir, elsewhere, _ = installed
    out = elsewhere / "walk.json"
    _run(bin_dir / "t2m", "generate", "a person walks forward", "--duration", "2", "--seed", "3", "-o", out,
         cwd=elsewhere)
    motion = json.loads(out.read_text())
    assert len(motion["frames"]) == 40 and motion["model"]["name"] == "t2m-bandai-hifigpt-minilm"


def test_serve_from_anywhere_with_the_embedded_model(installed):
    bin_dir, elsewhere, _ = installed
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    server = subprocess.Popen([str(bin_dir / "t2m"), "serve", "--host", "127.0.0.1", "--port", str(port)],
                              cwd=elsewhere, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                              env=_clean_env())
    try:
        health = _wait_ready(f"http://127.0.0.1:{port}/health", server)
        assert health["model"]["name"] == "t2m-bandai-hifigpt-minilm" and health["service_version"] == t2m.__version__
        request = urllib.request.Request(
            f"http://127.0.0.1:{port}/generate", method="POST", headers={"content-type": "application/json"},
            data=json.dumps({"segments": [{"text": "a person waves with the right hand", "duration": 2.0}],
                             "seed": 1}).encode())
        with urllib.request.urlopen(request, timeout=60) as answer:
            assert answer.status == 200 and len(json.loads(answer.read())["frames"]) == 40
    finally:
        server.terminate()
        server.wait(timeout=30)


def _wait_ready(url: str, server: subprocess.Popen, timeout_s: float = 90) -> dict:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if server.poll() is not None:
            raise AssertionError(f"t2m serve exited: {server.stderr.read().decode()[-2000:] if server.stderr else ''}")
        try:
            with urllib.request.urlopen(url, timeout=2) as answer:
                if answer.status == 200:
                    return json.loads(answer.read())
        except OSError:
            pass
        time.sleep(0.3)
    raise AssertionError(f"{url} not ready after {timeout_s} s")
