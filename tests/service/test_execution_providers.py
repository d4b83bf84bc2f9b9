"""T2M_EXECUTION_PROVIDERS / T2M_IO_BINDING: parsed, mapped to onnxruntime's providers, and a provider the installed
onnxruntime lacks refused at start-up in one line naming the setting (never mid-request)."""
from __future__ import annotations

import onnxruntime as ort
import pytest
from pydantic import ValidationError

from t2m.cli.main import main
from t2m.runtime.execution import Execution, ProviderError, check_available, ort_providers
from t2m.service.settings import Settings

HAS_CUDA = "CUDAExecutionProvider" in ort.get_available_providers()


def test_cpu_is_the_default_and_binds_nothing(monkeypatch):
    monkeypatch.delenv("T2M_EXECUTION_PROVIDERS", raising=False)
    monkeypatch.delenv("T2M_IO_BINDING", raising=False)
    settings = Settings()
    assert settings.execution_providers == ["cpu"] and settings.io_binding == "auto"
    assert settings.execution.ort_providers == ["CPUExecutionProvider"] and not settings.execution.binds


def test_environment_lists_are_parsed(monkeypatch):
    monkeypatch.setenv("T2M_EXECUTION_PROVIDERS", " cuda , cuda,cpu")
    monkeypatch.setenv("T2M_IO_BINDING", "off")
    settings = Settings()
    assert settings.execution_providers == ["cuda", "cpu"]
    assert not settings.execution.binds                       # forced off even with CUDA


def test_cuda_means_cuda_then_cpu_and_binds_by_default():
    execution = Execution(("cuda",))
    assert execution.ort_providers == ["CUDAExecutionProvider", "CPUExecutionProvider"] and execution.binds
    assert Execution(("cpu",), io_binding="on").binds
    assert ort_providers(["cpu", "cuda"]) == ["CPUExecutionProvider", "CUDAExecutionProvider"]


@pytest.mark.parametrize("value", ["tpu", "", "cuda,rocm"])
def test_unknown_or_empty_provider_lists_are_refused_naming_the_field(monkeypatch, value):
    monkeypatch.setenv("T2M_EXECUTION_PROVIDERS", value)
    with pytest.raises(ValidationError, match="execution_providers"):
        Settings()


def test_unknown_provider_name_names_the_setting():
    with pytest.raises(ProviderError, match="T2M_EXECUTION_PROVIDERS: unknown provider 'tpu'"):
        Execution(("tpu",))


def test_a_missing_provider_is_one_line_naming_the_setting_and_the_package():
    with pytest.raises(ProviderError) as raised:
        check_available(["cuda"], available=["CPUExecutionProvider"])
    message = str(raised.value)
    assert "\n" not in message and message.startswith("T2M_EXECUTION_PROVIDERS=cuda: ")
    assert "CUDAExecutionProvider" in message and "onnxruntime-gpu" in message
    check_available(["cuda"], available=["CUDAExecutionProvider", "CPUExecutionProvider"])    # no error


def test_a_session_that_fell_back_to_cpu_is_refused():
    class FellBack:
        def get_providers(self):
            return ["CPUExecutionProvider"]

    with pytest.raises(ProviderError, match="could not start CUDAExecutionProvider"):
        Execution(("cuda",)).check_session(FellBack(), "gpt_step.onnx")
    Execution(("cpu",)).check_session(FellBack(), "gpt_step.onnx")


@pytest.mark.skipif(HAS_CUDA, reason="this onnxruntime has CUDA: nothing to refuse")
def test_loading_a_bundle_on_a_missing_provider_fails_before_any_session(random_bundle):
    from t2m.runtime.engine import OnnxEngine

    with pytest.raises(ProviderError, match="T2M_EXECUTION_PROVIDERS=cuda"):
        OnnxEngine.load(random_bundle, execution=Execution(("cuda",)))


@pytest.mark.skipif(HAS_CUDA, reason="this onnxruntime has CUDA: nothing to refuse")
def test_serve_refuses_a_missing_provider_in_one_line(capsys, monkeypatch):
    monkeypatch.setenv("T2M_EXECUTION_PROVIDERS", "cpu")     # recorded, so the value `serve` sets is undone
    assert main(["serve", "--providers", "cuda"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "T2M_EXECUTION_PROVIDERS=cuda" in err and "onnxruntime-gpu" in err


def test_serve_refuses_an_unknown_provider_in_one_line(capsys, monkeypatch):
    monkeypatch.setenv("T2M_EXECUTION_PROVIDERS", "cpu")     # recorded, so the value `serve` sets is undone
    assert main(["serve", "--providers", "cpu,tpu"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "unknown provider 'tpu'" in err


def test_serve_leaves_the_environment_as_it_found_it(monkeypatch):
    """Control for the two tests above: the environment they ran in is the default one again."""
    import os

    assert os.environ.get("T2M_EXECUTION_PROVIDERS") in (None, "cpu")


def test_int8_step_graphs_on_a_gpu_provider_name_the_float_copy_to_serve(caplog):
    import json
    import logging

    from t2m.bundles import DEFAULT_BUNDLE
    from t2m.runtime.bundle_loader import _warn_int8_on_gpu

    raw = json.loads((DEFAULT_BUNDLE / "manifest.json").read_text())
    with caplog.at_level(logging.WARNING, logger="t2m.runtime.bundle_loader"):
        _warn_int8_on_gpu(raw, DEFAULT_BUNDLE, Execution(("cpu",)))
        assert not caplog.records                                   # CPU: int8 is the fast rule there
        _warn_int8_on_gpu({**raw, "quantization": {"text_encoder": "int8-dynamic"}}, DEFAULT_BUNDLE,
                          Execution(("cuda",)))
        assert not caplog.records                                   # the text encoder runs once per sentence
        _warn_int8_on_gpu(raw, DEFAULT_BUNDLE, Execution(("cuda",)))
    [record] = caplog.records
    assert "residual_step, temporal_step are int8," in record.message and "--scheme float32" in record.message
