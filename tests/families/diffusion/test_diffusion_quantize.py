"""Quantising the diffusion family's denoiser:
`t2m quantize` on MDM and DiP bundles and `t2m import mdm|dip --quantize`. The denoiser really changes (MatMulInteger,
MatMulNBits, float16 weights), the manifest (`quantization.denoiser`) and the card say so, and the parity says what
a diffusion model can: no tokens, the largest x0 difference on the float32 trajectory and how far the served joints
moved. Small random releases here; the released sizes in the slow test at the end.

Bounds, and why: x0 differences relative to the float32 x0 scale, measured on these random models (MDM, DiP) at
int8 0.021-0.025, int4 0.11-0.15, fp16 0.0006-0.0007; the bounds (0.1, 0.35, 0.005) are 2-7x that, so that another
CPU or onnxruntime version passes, while the control (four denoiser layers' int8 weights doubled) lands far outside.
Joints are not bounded: a diffusion run feeds each step's x0 into the next, and DiP's windows start from the last
one's frames, so on random weights the drift says nothing about a trained model (0.03-0.07 m here at int8, 4.3 m
for DiP at the released sizes).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
import pytest

from t2m.export.writing.bundle_parity import compare_bundles
from t2m.families.diffusion.mdm_release import RELEASE_SIZES, make_release, small_clip_archive  # type: ignore[import-not-found]
from t2m.families.diffusion.random_bundle import build_random_diffusion_bundle
from tests.export.quantized_copies import printed_json, run_t2m, with_doubled_weights  # type: ignore[import-not-found]
from tests.shared_data import HUMANML3D_SAMPLE

OPS = {"int8": "MatMulInteger", "int4": "MatMulNBits"}
LABELS = {"int8": "int8-dynamic-rows", "int4": "int4-matmulnbits", "fp16": "fp16"}
X0_BOUND = {"int8": 0.1, "int4": 0.35, "fp16": 0.005}


def check_x0(report: dict, scheme: str) -> None:
    graph = report["graphs"]["denoiser.onnx"]
    assert graph["output"] == "x0" and graph["calls"] > 0
    assert 0 < graph["max_abs_logit_diff"] <= X0_BOUND[scheme] * max(1.0, graph["max_abs_logit"]), graph
    assert report["tokens"] == 0 and np.isfinite(report["max_joint_diff_m"]) and report["max_joint_diff_m"] > 0


@pytest.fixture(scope="module")
def bundles(tmp_path_factory):
    root = tmp_path_factory.mktemp("diffusion-quantize")
    for arch in ("mdm", "dip"):
        build_random_diffusion_bundle(root / arch, arch=arch, seed=5)
    return root


@pytest.mark.parametrize("arch", ["mdm", "dip"])
@pytest.mark.parametrize("scheme", ["int8", "int4", "fp16"])
def test_quantize_a_diffusion_bundle_and_measure_it_as_served(bundles, arch, scheme, tmp_path):
    out = tmp_path / scheme
    code, stdout = run_t2m("quantize", str(bundles / arch), "-o", str(out), "--scheme", scheme)
    assert code == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["quantization"]["denoiser"] == LABELS[scheme]
    graph = onnx.load(str(out / "denoiser.onnx"))
    if scheme in OPS:
        assert any(node.op_type == OPS[scheme] for node in graph.graph.node)
    else:
        assert any(init.data_type == onnx.TensorProto.FLOAT16 for init in graph.graph.initializer)
    report = printed_json(stdout)["quantization"]
    check_x0(report, scheme)
    assert report["runs"] == 2 and report["seconds"] == 2.0         # the family's own parity requests
    card = (out / "MODEL_CARD.md").read_text()
    assert "no tokens to compare" in card and "max |x0 diff|" in card
    summary = stdout.strip().splitlines()[-1]
    assert f"denoiser.onnx {LABELS[scheme]}" in summary and "joints within" in summary and "x0 diff" in summary


def test_a_wrongly_quantised_denoiser_is_far_outside_the_bound(bundles, tmp_path):
    """The control: the int8 weights of the denoiser's first four integer MatMuls doubled; the comparison that
    passes the real quantisation fails it."""
    src = tmp_path / "int8"
    assert run_t2m("quantize", str(bundles / "mdm"), "-o", str(src), "--parity-runs", "0")[0] == 0
    out = with_doubled_weights(src, tmp_path / "wrong", "denoiser.onnx", lambda node: True)
    good = compare_bundles(bundles / "mdm", src, ["denoiser.onnx"], runs=2, seconds=2.0).as_dict()
    wrong = compare_bundles(bundles / "mdm", out, ["denoiser.onnx"], runs=2, seconds=2.0).as_dict()
    check_x0(good, "int8")
    with pytest.raises(AssertionError):
        check_x0(wrong, "int8")


def _mdm_source(root: Path, **sizes) -> list[str]:
    folder, _ = make_release(root / "release", "fifty", **sizes)
    return [str(folder), "--clip", str(small_clip_archive(root)), "--humanml3d", str(HUMANML3D_SAMPLE)]


def test_import_mdm_quantize_int8_writes_the_quantised_denoiser_and_a_float32_import_says_what_int8_does(
        tmp_path):
    source = _mdm_source(tmp_path)
    code, stdout = run_t2m("import", "mdm", *source, "--quantize", "int8", "-o", str(tmp_path / "int8"))
    assert code == 0
    manifest = json.loads((tmp_path / "int8" / "manifest.json").read_text())
    assert manifest["quantization"]["denoiser"] == "int8-dynamic-rows"
    check_x0(printed_json(stdout)["quantization"], "int8")
    assert "denoiser.onnx int8-dynamic-rows" in stdout.strip().splitlines()[-1]
    assert "int8 (`--quantize int8`" not in stdout
    code, stdout = run_t2m("import", "mdm", *source, "--skip-parity", "-o", str(tmp_path / "float32"))
    assert code == 0 and stdout.strip().splitlines()[-1].startswith("int8 (`--quantize int8`")
    assert not (json.loads((tmp_path / "float32" / "manifest.json").read_text()).get("quantization") or {}).get(
        "denoiser")


@pytest.mark.slow
@pytest.mark.parametrize("name", ["fifty", "dip"])
def test_released_sizes_quantised_diffusion_import(name, tmp_path, capsys):
    """MDM-50 and DiP at their released sizes (random weights, the small text encoders): int8 against the float32
    import, two seeded 2 s requests. Prints the figures."""
    from t2m.families.diffusion.mdm_release import small_bert_folder  # type: ignore[import-not-found]

    folder, _ = make_release(tmp_path / "release", name, RELEASE_SIZES)
    text = (["--bert", str(small_bert_folder(tmp_path))] if name == "dip"
            else ["--clip", str(small_clip_archive(tmp_path))])
    command = "dip" if name == "dip" else "mdm"
    code, stdout = run_t2m("import", command, str(folder), *text, "--humanml3d", str(HUMANML3D_SAMPLE),
                           "--skip-parity", "--quantize", "int8", "-o", str(tmp_path / "int8"))
    assert code == 0
    report = printed_json(stdout)["quantization"]
    check_x0(report, "int8")
    graph = report["graphs"]["denoiser.onnx"]
    with capsys.disabled():
        print(f"\n{name} int8: max |x0 diff| {graph['max_abs_logit_diff']:.3g} (x0 up to {graph['max_abs_logit']:.3g}),"
              f" joints within {report['max_joint_diff_m']:.3g} m over {report['runs']} seeded {report['seconds']:g} s"
              " requests")
