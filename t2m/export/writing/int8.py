"""A copy of a GPT bundle with a quantised step graph: gpt_step.onnx as int8 (dynamic, 7-bit weights; the shipped
rule) or int4 (MatMulNBits weights, int8 compute; opt-in, for release-size models bound by memory bandwidth), the
manifest's `quantization.gpt_step` and files table rewritten by write_bundle, so the copy is verified like any
exported bundle.

Used to measure a quantised step graph as served (`t2m eval --bundle`, the probes) before shipping it, to ship it,
and by `t2m quantize` for any GPT-family bundle (an imported T2M-GPT release included).
"""
from __future__ import annotations

import json
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from t2m.bundle import MANIFEST_NAME
from t2m.export.kit.checks import INT8_LABEL
from t2m.export.writing.bundle import check_out_dir, write_bundle

__all__ = ["INT4_LABEL", "SCHEMES", "quantize_bundle_gpt"]

INT4_LABEL = "int4-matmulnbits"
SCHEMES = ("int8", "int4")


def _quantizer(scheme: str) -> tuple[Callable[[Path, Path], Path], str]:
    from t2m.export.writing.quantize import quantize_graph, quantize_graph_int4

    if scheme == "int8":
        return quantize_graph, INT8_LABEL
    if scheme == "int4":
        return quantize_graph_int4, INT4_LABEL
    raise ValueError(f"scheme must be one of {', '.join(SCHEMES)}, got {scheme!r}")


def quantize_bundle_gpt(src: str | Path, out: str | Path, version: str | None = None,
                        scheme: str = "int8") -> dict[str, Any]:
    """Write `src` with a quantised gpt_step.onnx to `out` (may equal `src`); returns the written manifest.

    `version` replaces the manifest's version (a shipped bundle whose outputs change gets a new one)."""
    quantize, label = _quantizer(scheme)
    src, out = Path(src), Path(out)
    if not (src / MANIFEST_NAME).is_file():
        raise ValueError(f"{src}: no {MANIFEST_NAME} (not a bundle directory)")
    manifest = json.loads((src / MANIFEST_NAME).read_text(encoding="utf-8"))
    if manifest.get("family", "gpt") != "gpt":
        raise ValueError(f"{src}: only GPT-family bundles have gpt_step.onnx (this one is {manifest['family']!r})")
    if (manifest.get("quantization") or {}).get("gpt_step"):
        raise ValueError(f"{src}: gpt_step.onnx is already {manifest['quantization']['gpt_step']}")
    names = list(manifest["files"])
    with tempfile.TemporaryDirectory(prefix=f"{scheme}-bundle-") as tmp:
        staged = Path(tmp)
        for name in names:
            (staged / name).parent.mkdir(parents=True, exist_ok=True)
            if name == "gpt_step.onnx":
                quantize(src / name, staged / name)
            else:
                shutil.copyfile(src / name, staged / name)
        manifest["quantization"] = {**(manifest.get("quantization") or {}), "gpt_step": label}
        if version is not None:
            manifest["version"] = version
        check_out_dir(out)
        return write_bundle(out, {name: staged / name for name in names}, manifest)
