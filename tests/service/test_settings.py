"""Settings come from T2M_* environment variables (or arguments), with the embedded model as the default bundle."""
from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from t2m.service.settings import Settings, default_bundle_path
from tests.service.conftest import REPO


def test_defaults(monkeypatch):
    for name in ("T2M_MODEL_DIR", "T2M_BUNDLE_PATH", "T2M_API_KEY", "T2M_CORS_ORIGINS", "T2M_INTRA_OP_THREADS"):
        monkeypatch.delenv(name, raising=False)
    settings = Settings()
    assert settings.intra_op_threads == 1     # measured faster than onnxruntime's all-cores choice (docs/service.md)
    assert settings.bundle_path == default_bundle_path() == REPO / "t2m" / "bundles" / "default"
    assert settings.api_key is None and settings.cors_origins == []
    assert settings.max_queue >= 1 and settings.request_timeout_s > 0 and settings.max_body_bytes >= 1024
    # a half-sent request is dropped within seconds, long before nginx's own 60 s defaults would
    assert (settings.header_timeout_s, settings.body_timeout_s) == (15.0, 30.0)


def test_environment(monkeypatch):
    monkeypatch.setenv("T2M_MODEL_DIR", "/models/mine")
    monkeypatch.setenv("T2M_MAX_QUEUE", "3")
    monkeypatch.setenv("T2M_REQUEST_TIMEOUT_S", "12.5")
    monkeypatch.setenv("T2M_API_KEY", "zq-secret-91")
    monkeypatch.setenv("T2M_CORS_ORIGINS", "https://a.example, https://b.example")
    monkeypatch.setenv("T2M_INTRA_OP_THREADS", "2")
    monkeypatch.setenv("T2M_HEADER_TIMEOUT_S", "2.5")
    monkeypatch.setenv("T2M_BODY_TIMEOUT_S", "4")
    settings = Settings()
    assert (settings.header_timeout_s, settings.body_timeout_s) == (2.5, 4.0)
    assert settings.bundle_path == Path("/models/mine")
    assert settings.max_queue == 3 and settings.request_timeout_s == 12.5 and settings.intra_op_threads == 2
    assert settings.api_key.get_secret_value() == "zq-secret-91" and "zq-secret-91" not in repr(settings)
    assert settings.cors_origins == ["https://a.example", "https://b.example"]
    monkeypatch.setenv("T2M_BUNDLE_PATH", "/models/other")          # the explicit name wins over the alias
    assert Settings().bundle_path == Path("/models/other")


def test_empty_api_key_means_none(monkeypatch):
    monkeypatch.setenv("T2M_API_KEY", "")
    assert Settings().api_key is None


@pytest.mark.parametrize("field, value", [("max_queue", 0), ("request_timeout_s", 0), ("max_body_bytes", 10),
                                          ("engine_workers", 0), ("intra_op_threads", -1),
                                          ("header_timeout_s", 0), ("body_timeout_s", -1)])
def test_bad_values_are_refused_naming_the_field(field, value):
    with pytest.raises(ValidationError, match=field):
        Settings(**{field: value})


def test_the_service_limits_numpys_blas_threads_at_start_up(make_client, random_bundle):
    """T2M_BLAS_THREADS (1 by default) holds every BLAS of the serving process (numpy's, and scipy's that the loads
    bring) to that many threads, so that they do not spin beside onnxruntime's; 0 leaves their own choice. (Not
    undone afterwards: OpenBLAS 0.3.31 ignores a limit set from another thread once the main thread has set one, so
    the test sets none there.)"""
    from threadpoolctl import threadpool_info

    def blas_threads() -> dict[str, int]:
        return {pool["filepath"]: pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"}

    before = blas_threads()
    if not before:
        pytest.skip("numpy has no BLAS thread pool threadpoolctl can see here")
    make_client(Settings(bundle_path=random_bundle, blas_threads=0))
    assert {path: blas_threads()[path] for path in before} == before
    make_client(Settings(bundle_path=random_bundle, blas_threads=1))
    assert set(blas_threads().values()) == {1}


def test_the_service_freezes_what_it_loaded_out_of_the_garbage_collectors_view(make_client, random_bundle):
    """T2M_GC_FREEZE (on by default): once the models are loaded, everything alive then is moved out of the
    collector's generations (gc.freeze), so collections during serving walk only what requests allocate; off, the
    collector is left as it is."""
    import gc

    gc.unfreeze()
    try:
        make_client(Settings(bundle_path=random_bundle, gc_freeze=False))
        assert gc.get_freeze_count() == 0
        client = make_client(Settings(bundle_path=random_bundle))
        frozen = gc.get_freeze_count()
        assert frozen > 10_000     # the app, onnxruntime's and the tokenizers' Python objects, the loaded modules
        assert client.post("/generate", json={"segments": [{"text": "a person walks", "duration": 1.0}]}
                           ).status_code == 200
    finally:
        gc.unfreeze()
