"""`t2m generate` (no server) and `t2m serve` (the container's command) on the tiny random bundle."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np
import pytest

from t2m.cli.main import main
from tests.service.conftest import REPO, free_port


def _run(capsys, *argv: str) -> tuple[int, str]:
    code = main(["generate", *argv])
    return code, capsys.readouterr().err


def test_generate_writes_all_three_formats(random_bundle, tmp_path, capsys):
    args = ["a person walks forward", "--duration", "3", "--then", "a person waves", "--duration", "2",
            "--seed", "5", "--model", str(random_bundle)]
    code, err = _run(capsys, *args, "-o", str(tmp_path / "m.json"))
    assert code == 0, err
    data = json.loads((tmp_path / "m.json").read_text())
    assert np.asarray(data["frames"]).shape == (100, 22, 3) and data["seed"] == 5
    assert [(s["start_frame"], s["end_frame"]) for s in data["segments"]] == [(0, 60), (60, 100)]
    assert "100 frames" in err and "seed 5" in err

    assert _run(capsys, *args, "-o", str(tmp_path / "m.bvh"))[0] == 0
    from t2m.motion.bvh import read_bvh
    assert read_bvh(tmp_path / "m.bvh").num_frames == 100
    assert _run(capsys, *args, "-o", str(tmp_path / "m.glb"))[0] == 0
    assert (tmp_path / "m.glb").read_bytes()[:4] == b"glTF"


def test_generate_matches_the_api(random_bundle, tmp_path, capsys, app_client):
    """Same request, same seed: the CLI and the server produce the same motion."""
    code, err = _run(capsys, "walk", "--duration", "1.5", "--then", "jump", "--guidance", "2", "--top-k", "8",
                     "--temperature", "0.9", "--seed", "9", "--model", str(random_bundle),
                     "-o", str(tmp_path / "c.json"))
    assert code == 0, err
    served = app_client.post("/generate", json={
        "segments": [{"text": "walk", "duration": 1.5}, {"text": "jump", "duration": None}],
        "seed": 9, "guidance": 2, "top_k": 8, "temperature": 0.9}).json()
    assert json.loads((tmp_path / "c.json").read_text())["frames"] == served["frames"]


def test_duration_belongs_to_the_sentence_before_it():
    from t2m.cli.commands.generate import segments_from_args

    events = [("--then", "b"), ("--duration", 2.0), ("--then", "c")]
    assert segments_from_args("a", events) == [{"text": "a", "duration": None}, {"text": "b", "duration": 2.0},
                                               {"text": "c", "duration": None}]
    assert segments_from_args("a", [("--duration", 1.0)]) == [{"text": "a", "duration": 1.0}]


@pytest.mark.parametrize("argv, message", [
    (["walk", "--duration", "30"], "sentence 1 --duration"),
    (["walk", "--then", "  "], "sentence 2 text"),
    (["walk", "--temperature", "0"], "--temperature"),
    (["walk", "--top-k", "0"], "--top-k"),
    (["walk", "--top-k", "33"], "--top-k"),                                 # model limit: codebook of 32
    (["walk", "--guidance", "11"], "--guidance"),
    (["walk", "--duration", "1", "--duration", "2"], "two --duration"),
    (["walk", "--seed", "-4"], "--seed"),
])
def test_generate_rejects_bad_input_with_exit_2(random_bundle, tmp_path, capsys, argv, message):
    code, err = _run(capsys, *argv, "--model", str(random_bundle), "-o", str(tmp_path / "x.json"))
    assert code == 2
    assert message in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "x.json").exists()


def test_generate_rejects_bad_files(random_bundle, tmp_path, capsys):
    code, err = _run(capsys, "walk", "--model", str(random_bundle), "-o", str(tmp_path / "x.fbx"))
    assert code == 2 and ".fbx" in err
    code, err = _run(capsys, "walk", "--model", str(tmp_path / "none"), "-o", str(tmp_path / "x.json"))
    assert code == 2 and "does not exist" in err and len(err.strip().splitlines()) == 1
    with pytest.raises(SystemExit) as usage:
        main(["generate", "walk", "--duration", "soon", "-o", str(tmp_path / "x.json")])
    assert usage.value.code == 2


@pytest.mark.slow   # a fresh interpreter importing fastapi + onnxruntime + trimesh: 5-40 s on a busy machine
def test_serve_command_runs_the_service(random_bundle):
    """`t2m serve` as the container runs it: a subprocess answering /health and /generate."""
    port = free_port()
    env = {**os.environ, "T2M_INTRA_OP_THREADS": "1", "T2M_API_KEY": ""}
    process = subprocess.Popen([sys.executable, "-m", "t2m.cli", "serve", "--host", "127.0.0.1", "--port", str(port),
                                "--model", str(random_bundle)], cwd=REPO, env=env,
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        deadline = time.perf_counter() + 60
        while True:
            try:
                if httpx.get(f"http://127.0.0.1:{port}/health", timeout=2).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            assert process.poll() is None, process.stdout.read().decode()
            assert time.perf_counter() < deadline, "t2m serve did not become healthy"
            time.sleep(0.1)
        response = httpx.post(f"http://127.0.0.1:{port}/generate", timeout=30,
                              json={"segments": [{"text": "walk", "duration": 1.0}], "seed": 1})
        assert response.status_code == 200 and len(response.json()["frames"]) == 20
    finally:
        process.terminate()
        process.wait(10)


def test_serve_model_default_is_the_embedded_model(tmp_path):
    """`t2m serve --model default --model DIR`: the embedded model first (the default), DIR beside it."""
    from t2m.bundles import DEFAULT_BUNDLE
    from t2m.service.serve_command import model_environment

    assert model_environment([Path("default"), tmp_path / "momask"]) == {
        "T2M_BUNDLE_PATH": str(DEFAULT_BUNDLE), "T2M_EXTRA_MODEL_DIRS": str((tmp_path / "momask").resolve())}


def test_serve_refuses_a_missing_bundle(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("T2M_BUNDLE_PATH", "restored-after-the-test")   # `serve --model` sets it for its workers
    assert main(["serve", "--model", str(tmp_path / "none"), "--port", str(free_port())]) == 2
    assert "does not exist" in capsys.readouterr().err
