"""Fixtures of the service tests: a tiny random bundle (built once), engines, apps and a live uvicorn server."""
from __future__ import annotations

import json
import shutil
import socket
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
DEFAULT_MODEL = REPO / "t2m" / "bundles" / "default"      # T2M-HiFiGPT after 0.4.0
GPT_MODEL = REPO / "t2m" / "bundles" / "gpt"              # the 1-layer GPT, the default up to 0.4.0
MASKED_MODEL = REPO / "t2m" / "bundles" / "masked"        # the masked family (MoGenTS-style joint tokens)


@pytest.fixture(scope="session")
def random_bundle(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny random-weight bundle from export.bundle (codebook 32, max_tokens 50, length conditioning, guidance)."""
    import torch

    from t2m.families.gpt.random_bundle import build_random_bundle

    torch.set_num_threads(1)
    return build_random_bundle(tmp_path_factory.mktemp("bundle") / "random", seed=0)


@pytest.fixture(scope="session")
def second_bundle(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Another tiny random bundle with other limits, for serving two models: name t2m-random-b 0.0.1, codebook 64,
    max_tokens 25 (5 s segments), default guidance 2."""
    import torch

    from t2m.families.gpt.random_bundle import build_random_bundle

    torch.set_num_threads(1)
    return build_random_bundle(tmp_path_factory.mktemp("bundle") / "random-b", seed=1, name="t2m-random-b",
                               version="0.0.1", codebook_size=64, block_size=26, default_guidance=2.0)


@pytest.fixture(scope="session")
def masked_build() -> dict:
    """How `masked_bundle` is built (the PyTorch reference rebuilds the same models from it)."""
    return {"variant": "2d", "residual_layers": 2, "length_estimator": True, "steps": 4, "seed": 3}


@pytest.fixture(scope="session")
def masked_bundle(tmp_path_factory: pytest.TempPathFactory, masked_build: dict) -> Path:
    """A tiny random masked-family bundle (MoGenTS's 2D joint tokens, two residual layers, a length estimator)."""
    import torch

    from t2m.families.masked.random_bundle import build_random_masked_bundle

    torch.set_num_threads(1)
    return build_random_masked_bundle(tmp_path_factory.mktemp("masked") / "2d", **masked_build)


@pytest.fixture(scope="session")
def hifigpt_build() -> dict:
    """How `hifigpt_bundle` is built (the PyTorch reference rebuilds the same model from it)."""
    return {"depth": 3, "codebook_size": 16, "seed": 2}


@pytest.fixture(scope="session")
def hifigpt_bundle(tmp_path_factory: pytest.TempPathFactory, hifigpt_build: dict) -> Path:
    """A tiny random T2M-HiFiGPT bundle (three code depths, 8 frames per step), its parity checked."""
    import torch

    from t2m.families.hifigpt.random_bundle import build_random_hifigpt_bundle

    torch.set_num_threads(1)
    return build_random_hifigpt_bundle(tmp_path_factory.mktemp("hifigpt") / "bundle", check_parity=True,
                                       **hifigpt_build)


@pytest.fixture(scope="session")
def bundle_without_uncond(random_bundle: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The same graphs, declared as trained without an unconditional branch (manifest is not hashed)."""
    target = tmp_path_factory.mktemp("bundle") / "no-uncond"
    shutil.copytree(random_bundle, target)
    manifest = json.loads((target / "manifest.json").read_text())
    manifest["gpt"]["unconditional_branch"] = False
    (target / "manifest.json").write_text(json.dumps(manifest))
    return target


@pytest.fixture(scope="session")
def onnx_engine(random_bundle: Path):
    from t2m.runtime.engine import OnnxEngine

    return OnnxEngine.load(random_bundle, intra_op_threads=1)


@pytest.fixture(scope="session")
def default_model() -> Path:
    if not (DEFAULT_MODEL / "manifest.json").is_file():
        pytest.skip(f"the real default model is not committed yet ({DEFAULT_MODEL / 'manifest.json'} is absent)")
    return DEFAULT_MODEL


@pytest.fixture(scope="session")
def gpt_model() -> Path:
    """The embedded GPT-family model: tests of what only that family does (its recorded outputs, continuous batching
    of its KV-cached step graph) use it whatever the default is."""
    if not (GPT_MODEL / "manifest.json").is_file():
        pytest.skip(f"the embedded GPT model is not committed ({GPT_MODEL / 'manifest.json'} is absent)")
    return GPT_MODEL


@pytest.fixture(scope="session")
def masked_model() -> Path:
    """The embedded masked-family model."""
    if not (MASKED_MODEL / "manifest.json").is_file():
        pytest.skip(f"the embedded masked model is not committed ({MASKED_MODEL / 'manifest.json'} is absent)")
    return MASKED_MODEL


def wait_ready(client, timeout_s: float = 20.0) -> None:
    """Poll /health until 200 (the bundle loads in a background thread)."""
    deadline = time.perf_counter() + timeout_s
    while time.perf_counter() < deadline:
        response = client.get("/health")
        if response.status_code == 200:
            return
        assert response.status_code == 503, response.text
        time.sleep(0.02)
    raise AssertionError(f"service not ready after {timeout_s} s: {response.json()}")


@pytest.fixture
def make_client() -> Iterator[Callable]:
    """make_client(settings, engine_factory=None, ready=True) -> a started fastapi TestClient (closed afterwards)."""
    from fastapi.testclient import TestClient

    from t2m.service.app import create_app

    opened = []

    def make(settings, engine_factory=None, ready: bool = True, raise_server_exceptions: bool = True):
        client = TestClient(create_app(settings, engine_factory=engine_factory),
                            raise_server_exceptions=raise_server_exceptions)
        client.__enter__()
        opened.append(client)
        if ready:
            wait_ready(client)
        return client

    yield make
    for client in opened:
        client.__exit__(None, None, None)


@pytest.fixture(scope="session")
def app_client(random_bundle: Path):
    """A TestClient on the real OnnxEngine and the random bundle."""
    from fastapi.testclient import TestClient

    from t2m.service.app import create_app
    from t2m.service.settings import Settings

    with TestClient(create_app(Settings(bundle_path=random_bundle, intra_op_threads=1))) as client:
        wait_ready(client)
        yield client


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


class LiveServer:
    """uvicorn serving an app on 127.0.0.1:<free port> in a thread; `config` adds uvicorn.Config options."""

    def __init__(self, app, **config) -> None:
        import uvicorn

        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=self.port, log_level="warning",
                                                    lifespan="on", **config))
        self.thread = threading.Thread(target=self.server.run, daemon=True)

    def __enter__(self) -> LiveServer:
        import httpx

        self.thread.start()
        deadline = time.perf_counter() + 30
        while time.perf_counter() < deadline:
            try:
                if httpx.get(self.url + "/health", timeout=2).status_code == 200:
                    return self
            except httpx.TransportError:
                pass
            time.sleep(0.05)
        raise AssertionError(f"uvicorn on {self.url} did not become ready")

    def __exit__(self, *exc: object) -> None:
        self.server.should_exit = True
        self.thread.join(10)


@pytest.fixture(scope="session")
def live_server(random_bundle: Path) -> Iterator[LiveServer]:
    """The real app (OnnxEngine, random bundle) on a real uvicorn, with an API key."""
    from t2m.service.app import create_app
    from t2m.service.settings import Settings

    app = create_app(Settings(bundle_path=random_bundle, intra_op_threads=1, api_key="test-key"))
    with LiveServer(app) as server:
        yield server
