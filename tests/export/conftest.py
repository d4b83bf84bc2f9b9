"""Shared fixtures for the export tests: one thread for torch and onnxruntime, offline transformers."""
from __future__ import annotations

import os

import pytest

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")


@pytest.fixture(autouse=True, scope="session")
def _one_torch_thread():
    import torch

    torch.set_num_threads(1)


@pytest.fixture(scope="session")
def random_bundle(tmp_path_factory):
    """A tiny random bundle (length conditioning, guidance branch), built once for the session."""
    from t2m.families.gpt.random_bundle import build_random_bundle

    return build_random_bundle(tmp_path_factory.mktemp("bundle") / "random")


@pytest.fixture(scope="session")
def exported_runs(tmp_path_factory):
    """`t2m export` (in-process) of tiny runs with the real MiniLM text encoder and an int8 GPT step graph.

    Returns (bundle_dir, printed stdout). The bundle's text graph is float32 MiniLM: the text parity and
    int8 tests reuse it, so MiniLM is exported once per session.
    """
    import contextlib
    import io

    from export_run_fixtures import make_runs

    from t2m.cli.main import main as t2m

    root = tmp_path_factory.mktemp("runs")
    vq_run, gpt_run, _ = make_runs(root)
    out = root / "bundle"
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        code = t2m(["export", "--vq", str(vq_run), "--gpt", str(gpt_run), "--int8", "gpt", "--version", "0.2.0",
                    "-o", str(out)])
    assert code == 0
    return out, stdout.getvalue()


@pytest.fixture(scope="session")
def minilm_encoder():
    from t2m.model.networks.text_encoders import MiniLMEncoder

    return MiniLMEncoder()
