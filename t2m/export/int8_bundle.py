"""An int8-GPT copy of a GPT bundle: gpt_step.onnx dynamically quantised (7-bit weights), manifest and files table
rewritten by write_bundle, so the copy is verified like any exported bundle.

Used to measure an int8 step graph as served (`t2m eval --bundle`, the probes) before shipping it, and to ship it.
"""
from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path
from typing import Any

from t2m.bundle import MANIFEST_NAME
from t2m.export.bundle import check_out_dir, write_bundle
from t2m.export.exporter import INT8_LABEL

__all__ = ["quantize_bundle_gpt"]


def quantize_bundle_gpt(src: str | Path, out: str | Path, version: str | None = None) -> dict[str, Any]:
    """Write `src` with an int8 gpt_step.onnx to `out` (may equal `src`); returns the written manifest.

    `version` replaces the manifest's version (a shipped bundle whose outputs change gets a new one)."""
    from t2m.export.quantize import quantize_graph

    src, out = Path(src), Path(out)
    manifest = json.loads((src / MANIFEST_NAME).read_text(encoding="utf-8"))
    if manifest.get("family", "gpt") != "gpt":
        raise ValueError(f"{src}: only GPT-family bundles have gpt_step.onnx (this one is {manifest['family']!r})")
    if (manifest.get("quantization") or {}).get("gpt_step"):
        raise ValueError(f"{src}: gpt_step.onnx is already {manifest['quantization']['gpt_step']}")
    names = list(manifest["files"])
    with tempfile.TemporaryDirectory(prefix="int8-bundle-") as tmp:
        staged = Path(tmp)
        for name in names:
            (staged / name).parent.mkdir(parents=True, exist_ok=True)
            if name == "gpt_step.onnx":
                quantize_graph(src / name, staged / name)
            else:
                shutil.copyfile(src / name, staged / name)
        manifest["quantization"] = {**(manifest.get("quantization") or {}), "gpt_step": INT8_LABEL}
        if version is not None:
            manifest["version"] = version
        check_out_dir(out)
        return write_bundle(out, {name: staged / name for name in names}, manifest)
