"""benchmarks/gpu_suite.py end to end on the CPU with toy release sizes: it prints its table, writes its JSON and
times both columns (onnxruntime with bound and numpy caches, PyTorch eager); on CPU it must not report CUDA as
missing. Numbers are printed, never asserted."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.timeout(300)
def test_gpu_suite_runs_on_cpu_with_toy_sizes(tmp_path):
    pytest.importorskip("torch")
    pytest.importorskip("onnx")
    result = subprocess.run(
        [sys.executable, str(REPO / "benchmarks" / "gpu_suite.py"), "--out", str(tmp_path), "--device", "cpu",
         "--batches", "2", "--repeats", "1", "--tiny", "--models", "t2m-gpt-release,momask-release"],
        cwd=REPO, capture_output=True, text=True, timeout=280, env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin",
                                                                   "OMP_NUM_THREADS": "1"})
    assert result.returncode == 0, result.stderr[-2000:]
    assert "missing:" not in result.stdout
    record = json.loads((tmp_path / "gpu_suite.json").read_text())
    methods = {(row["model"].split(" ")[0], row["method"]) for row in record["rows"]}
    assert methods == {("t2m-gpt-release", "onnxruntime cpu, I/O binding"),
                       ("t2m-gpt-release", "onnxruntime cpu, numpy caches"),
                       ("t2m-gpt-release", "PyTorch eager cpu"),
                       ("momask-release", "onnxruntime cpu"), ("momask-release", "PyTorch eager cpu")}
    assert all(row["batch"] == 2 and row["ms_motion"] > 0 for row in record["rows"]) and not record["failures"]
    table = [line for line in result.stdout.splitlines() if line.startswith("| ")]
    assert table[0].startswith("| model | batch | method") and len(table) == 1 + 1 + len(record["rows"])


def test_gpu_suite_says_what_is_missing_for_cuda(tmp_path):
    """Without onnxruntime-gpu and a CUDA device (this machine) a CUDA run names both and stops cleanly."""
    pytest.importorskip("torch")
    import onnxruntime
    import torch

    if torch.cuda.is_available() or "CUDAExecutionProvider" in onnxruntime.get_available_providers():
        pytest.skip("this machine has CUDA")
    result = subprocess.run([sys.executable, str(REPO / "benchmarks" / "gpu_suite.py"), "--out", str(tmp_path)],
                            cwd=REPO, capture_output=True, text=True, timeout=120, env={"PYTHONPATH": str(REPO),
                                                                                       "PATH": "/usr/bin:/bin"})
    assert result.returncode == 3
    assert "missing: onnxruntime" in result.stdout and "missing: torch" in result.stdout
    assert "no table" in result.stdout
