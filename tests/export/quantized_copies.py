"""What the quantisation tests share: running the CLI in-process, reading the JSON it prints, and the control copy
of an int8 bundle whose weights are wrong (tests/export/test_import_quantize.py, test_diffusion_quantize.py)."""
from __future__ import annotations

import contextlib
import io
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import onnx

from t2m.cli.main import main as t2m
from t2m.export.writing.bundle import write_bundle


def run_t2m(*argv: str) -> tuple[int, str]:
    """`t2m ARGV` in this process: (exit code, what it printed)."""
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        code = t2m(list(argv))
    return code, stdout.getvalue()


def printed_json(stdout: str) -> dict:
    """The JSON object an import or `t2m quantize` prints before its summary lines."""
    return json.loads(stdout[: stdout.rindex("}") + 1])


def with_doubled_weights(src: Path, out: Path, graph: str, chosen: Callable[[onnx.NodeProto], bool],
                         count: int = 4) -> Path:
    """A verified copy of the int8 bundle `src` at `out` whose `graph` has the int8 weights of its first `count`
    MatMulInteger nodes that `chosen` picks doubled (8-bit values read with the 7-bit scale): the control that a
    parity check must fail."""
    out.mkdir()
    manifest = json.loads((src / "manifest.json").read_text())
    for name in manifest["files"]:
        (out / name).write_bytes((src / name).read_bytes())
    model = onnx.load(str(out / graph))
    weights = {init.name: init for init in model.graph.initializer}
    for node in [node for node in model.graph.node if node.op_type == "MatMulInteger" and chosen(node)][:count]:
        if node.input[1] in weights:
            doubled = onnx.numpy_helper.to_array(weights[node.input[1]]).astype(np.int16) * 2
            weights[node.input[1]].CopyFrom(onnx.numpy_helper.from_array(doubled.clip(-128, 127).astype(np.int8),
                                                                         node.input[1]))
    onnx.save(model, str(out / graph))
    write_bundle(out, {name: out / name for name in manifest["files"]}, manifest)
    return out
