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
        [sys.executable, "-m", "benchmarks.gpu_suite", "--out", str(tmp_path), "--device", "cpu",
         "--batches", "2", "--repeats", "1", "--tiny", "--models", "t2m-gpt-release,momask-release"],
        cwd=REPO, capture_output=True, text=True, timeout=280, env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin",
                                                                   "OMP_NUM_THREADS": "1"})
    assert result.returncode == 0, result.stderr[-2000:]
    assert "missing:" not in result.stdout
    record = json.loads((tmp_path / "gpu_suite.json").read_text())
    methods = {(row["model"].split(" ")[0], row["method"]) for row in record["rows"]}
    assert methods == {("t2m-gpt-release", "onnxruntime cpu, I/O binding"),
                       ("t2m-gpt-release", "onnxruntime cpu, numpy caches"),
                       ("t2m-gpt-release", "onnxruntime cpu, fixed cache + CUDA graphs, no capture"),
                       ("momask-release", "onnxruntime cpu, CUDA graphs, no capture"),
                       ("t2m-gpt-release", "PyTorch eager cpu"),
                       ("momask-release", "onnxruntime cpu"), ("momask-release", "PyTorch eager cpu")}
    assert all(row["batch"] == 2 and row["ms_motion"] > 0 for row in record["rows"]) and not record["failures"]
    agreement = sorted(note for note in record["notes"] if "its codes equal to the plain onnxruntime ones" in note)
    assert len(agreement) == 2, record["notes"]
    assert "momask-release" in agreement[0] and ": 1176 of 1176 (batch 4" in agreement[0]  # 4 x 49 rows x 6 layers
    assert "t2m-gpt-release" in agreement[1] and ": 200 of 200 (batch 4" in agreement[1]   # 4 x 50 tokens
    table = [line for line in result.stdout.splitlines() if line.startswith("| ")]
    assert table[0].startswith("| model | batch | method") and len(table) == 1 + 1 + len(record["rows"])


@pytest.mark.timeout(300)
def test_gpu_suite_runs_the_default_model_in_several_processes_at_once(tmp_path):
    """--processes 2: two processes, each with its own sessions, generate and decode batches together; the row
    counts both processes' motions (batch 2 x 1)."""
    pytest.importorskip("torch")
    pytest.importorskip("onnx")
    result = subprocess.run(
        [sys.executable, "-m", "benchmarks.gpu_suite", "--out", str(tmp_path), "--device", "cpu",
         "--batches", "1", "--repeats", "1", "--models", "default", "--processes", "2"],
        cwd=REPO, capture_output=True, text=True, timeout=280, env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin",
                                                                   "OMP_NUM_THREADS": "1"})
    assert result.returncode == 0, result.stderr[-2000:]
    record = json.loads((tmp_path / "gpu_suite.json").read_text())
    (row,) = [row for row in record["rows"] if "processes" in row["method"]]
    assert row["method"] == "onnxruntime cpu, 2 processes x batch 1 (decode included)" and row["batch"] == 2
    assert row["ms_generate"] > 0 and not record["failures"]


def test_a_process_that_cannot_start_is_named_and_nothing_waits_for_it(tmp_path):
    """A process that fails before the common start (here: no CUDA provider) aborts the barrier: the others do not
    hang, and the failure comes back in one line; a release case is refused (its build writes files)."""
    pytest.importorskip("torch")
    import onnxruntime

    from benchmarks.gpu_processes import processes_wall_s

    if "CUDAExecutionProvider" in onnxruntime.get_available_providers():
        pytest.skip("this machine has CUDA")
    with pytest.raises(RuntimeError, match=r"(?i)cuda"):
        processes_wall_s("default", "shipped", tmp_path, "cuda", 2, 1, 1, timeout_s=120)
    with pytest.raises(ValueError, match="embedded cases"):
        processes_wall_s("momask-release", "shipped", tmp_path, "cpu", 2, 1, 1)


def test_gpu_suite_says_what_is_missing_for_cuda(tmp_path):
    """Without onnxruntime-gpu and a CUDA device (this machine) a CUDA run names both and stops cleanly."""
    pytest.importorskip("torch")
    import onnxruntime
    import torch

    if torch.cuda.is_available() or "CUDAExecutionProvider" in onnxruntime.get_available_providers():
        pytest.skip("this machine has CUDA")
    result = subprocess.run([sys.executable, "-m", "benchmarks.gpu_suite", "--out", str(tmp_path)],
                            cwd=REPO, capture_output=True, text=True, timeout=120, env={"PYTHONPATH": str(REPO),
                                                                                       "PATH": "/usr/bin:/bin"})
    assert result.returncode == 3
    assert "missing: onnxruntime" in result.stdout and "missing: torch" in result.stdout
    assert "no table" in result.stdout


def _git(repo: Path, *args: str) -> str:
    return subprocess.run(["git", *args], cwd=repo, check=True, capture_output=True, text=True).stdout


def test_the_wheel_travels_in_parts_and_comes_together_byte_for_byte(tmp_path):
    """tools/gpu/transport.sh on a fake wheel in a scratch repository: prepare splits the CUDA provider into
    parts of PART_MB, keep + unpack (what the device calls run) rebuild every file of the wheel exactly; slim takes
    the bundles out of git's index only (the files stay) and restore puts them back."""
    import os
    import zipfile

    repo = tmp_path / "repo"
    (repo / "tools" / "gpu").mkdir(parents=True)
    (repo / "tools" / "gpu" / "transport.sh").write_bytes((REPO / "tools" / "gpu" / "transport.sh").read_bytes())
    for bundle in ("default", "gpt", "masked"):
        (repo / "t2m" / "bundles" / bundle).mkdir(parents=True)
        (repo / "t2m" / "bundles" / bundle / "manifest.json").write_text("{}")
    _git(repo, "init", "-q")
    _git(repo, "add", ".")
    _git(repo, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "scratch")
    files = {"onnxruntime/capi/libonnxruntime_providers_cuda.so": os.urandom(3_000_000),
             "onnxruntime/__init__.py": b"__version__ = '0'\n",
             "onnxruntime_gpu-0.dist-info/METADATA": b"Name: onnxruntime-gpu\n"}
    wheel = tmp_path / "onnxruntime_gpu-0-cp312-cp312-manylinux_2_28_x86_64.whl"
    with zipfile.ZipFile(wheel, "w") as archive:
        for name, data in files.items():
            archive.writestr(name, data)
    script = ["bash", "tools/gpu/transport.sh"]
    env = {"PATH": "/usr/bin:/bin", "PART_MB": "1", "HOME": str(tmp_path), "KEEP_SM": "all"}   # no fatbin here

    def run(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([*script, *args], cwd=repo, env=env, capture_output=True, text=True)

    assert run("prepare", str(wheel)).returncode == 0
    parts = sorted(p.name for p in (repo / ".gpu").glob("cuda.xz.part-*"))
    assert len(parts) == 3          # 3 MB of random bytes do not compress: three 1 MB parts
    assert "/.gpu/" in (repo / ".git" / "info" / "exclude").read_text()
    assert run("keep", str(tmp_path / "kept")).returncode == 0
    assert run("unpack", str(tmp_path / "kept"), str(tmp_path / "site")).returncode == 0
    for name, data in files.items():
        assert (tmp_path / "site" / name).read_bytes() == data, name
    assert run("slim").returncode == 0
    assert not [f for f in _git(repo, "ls-files").split() if f.startswith("t2m/bundles/")]
    assert (repo / "t2m" / "bundles" / "gpt" / "manifest.json").exists()
    assert run("restore").returncode == 0
    assert len([f for f in _git(repo, "ls-files").split() if f.startswith("t2m/bundles/")]) == 3
    assert _git(repo, "status", "--porcelain") == ""
    bad = run("prepare", str(tmp_path / "missing.whl"))
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "no wheel" in bad.stderr


def test_gpu_profile_sums_onnxruntimes_profile_per_operator_on_cpu(tmp_path, capsys):
    """benchmarks/gpu_profile.py (the device check of where a step's time goes) runs here on the CPU provider: every
    node of the profiled run is summed per operator, and the node time is part of the session runs' time."""
    from benchmarks.gpu_profile import main

    assert main(["--out", str(tmp_path), "--device", "cpu", "--tiny", "--models", "t2m-gpt-release"]) == 0
    summary = json.loads((tmp_path / "profile_t2m-gpt-release.json").read_text())
    nodes = summary["nodes"]
    assert "MatMul (CPUExecutionProvider)" in nodes and all(entry["calls"] > 0 for entry in nodes.values())
    assert 0 < sum(entry["ms"] for entry in nodes.values()) <= summary["runs_ms"]
    assert "| operator (provider) | ms | calls | us per call |" in capsys.readouterr().out


def test_host_loop_prints_one_row_per_loop_batch_and_draw_group():
    """`t2m bench host-loop` (the decoding loops over instant steps; gpu_suite's "host loop alone" row): one table
    row per loop, batch and DRAW_GROUP size compared. Figures are printed, never asserted."""
    result = subprocess.run(
        [sys.executable, "-m", "t2m.cli", "bench", "host-loop", "--batches", "1,3", "--repeats", "1",
         "--draw-groups", "2,0", "--loops", "default,momask,t2m-gpt"], cwd=REPO, capture_output=True, text=True,
        timeout=120, env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin", "OMP_NUM_THREADS": "1"})
    assert result.returncode == 0, result.stderr[-2000:]
    rows = [[cell.strip() for cell in line.split("|")[1:4]] for line in result.stdout.splitlines()
            if line.startswith("| ") and not line.startswith(("| loop", "| ---"))]
    assert [(loop.split(" ")[0], group, batch) for loop, group, batch in rows] == [
        (loop, group, batch) for loop in ("default", "MoMask", "T2M-GPT") for batch in ("1", "3")
        for group in ("2", "all")]


def test_gpu_service_check_serves_an_import_with_and_without_cuda_graphs_on_cpu(tmp_path):
    """The device script for the service's CUDA-graph path, run here at small sizes: one row per setting and the
    two motions equal (on the CPU provider nothing is captured)."""
    pytest.importorskip("torch")
    pytest.importorskip("onnx")
    result = subprocess.run(
        [sys.executable, "-m", "benchmarks.gpu_service_check", "--device", "cpu", "--sizes", "small",
         "--repeats", "1", "--out", str(tmp_path)], capture_output=True, text=True, timeout=600, cwd=REPO)
    assert result.returncode == 0, result.stderr[-2000:]
    table = (tmp_path / "gpu_service_check.md").read_text()
    rows = [[cell.strip() for cell in line.split("|")[1:5]] for line in table.splitlines()
            if line.startswith("| ") and not line.startswith(("| model", "| ---"))]
    assert rows == [[model, scheme, "cpu", graphs] for model in ("MoMask", "T2M-GPT") for scheme in ("float32", "fp16")
                    for graphs in ("off", "on")]
    assert table.count("| [] |") == 8
    # the fixed-cache T2M-GPT step (float32 and fp16) draws what the plain step draws
    assert table.count("two motions: 0.00e+00 m") == 4
