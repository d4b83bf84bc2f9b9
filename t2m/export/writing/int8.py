"""A copy of a bundle with its token graphs quantised, for every family (the family seam's `quantizable_graphs`):
int8 (dynamic, 7-bit weights: MatMulInteger, activations quantised per row; the shipped rule; an int8 bundle whose
activations are quantised per tensor is rewritten per row: row_quantize.py), int4 (MatMulNBits weights, int8
compute; opt-in, for release-size models bound by memory bandwidth) or fp16 (float16 weights and compute, float32
inputs and outputs; for GPUs). The manifest's `quantization.<graph>` entries and files table are rewritten by
write_bundle, so the copy is verified like any exported bundle, and the copy's model card says what was quantised
and what it cost, measured against the float32 original as served (t2m.export.writing.bundle_parity).

Used to measure a quantised bundle as served (`t2m eval --bundle`, the probes) before shipping it, to ship it, by
`t2m quantize` for any family's bundle (an imported release included) and by `t2m import ... --quantize`.
"""
from __future__ import annotations

import functools
import json
import re
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from t2m.bundle import MANIFEST_NAME
from t2m.export.kit.checks import INT8_LABEL, INT8_LABELS, ROW_INT8_LABEL
from t2m.export.writing.bundle import check_out_dir, prepare_out_dir, write_bundle

__all__ = ["DEQUANTIZED_LABEL", "FP16_LABEL", "INT4_LABEL", "SCHEMES", "captured_graphs_to_convert", "quantize_bundle",
           "quantize_bundle_gpt", "quantized_graphs"]

INT4_LABEL = "int4-matmulnbits"
FP16_LABEL = "fp16"
DEQUANTIZED_LABEL = "float32-dequantized"
SCHEMES = ("int8", "int4", "fp16", "float32")
# schemes that also take int8-dynamic graphs: the GPU copies of the shipped int8 bundles (dequantised first) and
# int8 itself (an int8 bundle quantised per tensor rewritten per row)
FROM_INT8 = ("fp16", "float32", "int8")
WHAT = {
    INT8_LABEL: "int8 MatMul/Gemm weights (per channel, 7 bits) and embedding tables, activations quantised on the "
                "fly (MatMulInteger)",
    ROW_INT8_LABEL: "int8 MatMul/Gemm weights (per channel, 7 bits) and embedding tables, activations quantised on "
                    "the fly one row at a time (MatMulInteger; a request's result never depends on its batch)",
    INT4_LABEL: "int4 MatMul weights in blocks of 128 with int8 compute (MatMulNBits)",
    FP16_LABEL: "float16 weights and compute, float32 inputs and outputs (for GPUs; op types onnxruntime's "
                "converter blocks stay float32)",
    DEQUANTIZED_LABEL: "int8 weights dequantised to float32 MatMuls and tables (for GPUs: onnxruntime's CUDA "
                       "provider has no DynamicQuantizeLinear kernel)",
}


def _quantizer(scheme: str) -> tuple[Callable[[Path, Path], Path], str]:
    from t2m.export.writing.quantize import convert_graph_fp16, quantize_graph, quantize_graph_int4

    if scheme == "int8":
        return functools.partial(quantize_graph, per_row=True), ROW_INT8_LABEL
    if scheme == "int4":
        return quantize_graph_int4, INT4_LABEL
    if scheme == "fp16":
        return convert_graph_fp16, FP16_LABEL
    if scheme == "float32":
        from t2m.export.writing.dequantize import dequantize_graph

        return dequantize_graph, DEQUANTIZED_LABEL
    raise ValueError(f"scheme must be one of {', '.join(SCHEMES)}, got {scheme!r}")


def _from_int8(quantize: Callable[[Path, Path], Path]) -> Callable[[Path, Path], Path]:
    """`quantize` applied to the dequantised float graph of an int8-dynamic one."""
    from t2m.export.writing.dequantize import dequantize_graph

    def convert(src: Path, dst: Path) -> Path:
        with tempfile.TemporaryDirectory(prefix="dequantized-") as tmp:
            return quantize(dequantize_graph(src, Path(tmp) / src.name), dst)
    return convert


def family_of_manifest(manifest: dict[str, Any]) -> Any:
    """The manifest's model family (t2m.bundle.family.ModelFamily)."""
    from t2m.bundle import family_of, get_family

    return get_family(family_of(manifest))


def quantized_graphs(manifest: dict[str, Any]) -> tuple[str, ...]:
    """The graph files of this manifest's family that a quantisation rewrites (none: the family has none)."""
    return family_of_manifest(manifest).quantizable_graphs(manifest)


def captured_graphs_to_convert(manifest: dict[str, Any], scheme: str) -> tuple[str, ...]:
    """The family's captured graphs (the GPT's gpt_step_fixed.onnx, replayed as CUDA graphs) this bundle holds and
    `scheme` converts: fp16 only, as they exist for GPUs (int8 and int4 would make them slow there; they are float32
    already)."""
    if scheme != "fp16":
        return ()
    captured = family_of_manifest(manifest).captured_graphs(manifest)
    return tuple(name for name in captured if name in manifest.get("files", {}))


def _read_manifest(src: Path) -> dict[str, Any]:
    if not (src / MANIFEST_NAME).is_file():
        raise ValueError(f"{src}: no {MANIFEST_NAME} (not a bundle directory)")
    return json.loads((src / MANIFEST_NAME).read_text(encoding="utf-8"))


def quantize_bundle(src: str | Path, out: str | Path, version: str | None = None, scheme: str = "int8",
                    parity: bool = True, runs: int | None = None) -> tuple[dict[str, Any], dict[str, Any] | None]:
    """Write `src` with its family's token graphs quantised by `scheme` to `out` (with `parity`, `out` must differ
    from `src`: the float32 original is what the copy is measured against); returns (the written manifest, the parity
    report as a dict, or None without `parity`). `version` replaces the manifest's version (a shipped bundle whose
    outputs change gets a new one)."""
    from t2m.export.writing.bundle_parity import compare_bundles

    quantize, label = _quantizer(scheme)
    src, out = Path(src), Path(out)
    manifest = _read_manifest(src)
    graphs = quantized_graphs(manifest)
    if not graphs:
        raise ValueError(f"{src}: family {manifest.get('family', 'gpt')!r} declares no graphs to quantise")
    done = {name: (manifest.get("quantization") or {}).get(Path(name).stem) for name in graphs}
    from_int8 = scheme in FROM_INT8 and all(value in ((INT8_LABEL,) if scheme == "int8" else INT8_LABELS)
                                            for value in done.values())
    if from_int8 and scheme == "fp16":
        quantize = _from_int8(quantize)      # the float32 scheme's quantiser is the dequantiser itself
    elif from_int8 and scheme == "int8":
        from t2m.export.writing.row_quantize import row_quantize_graph

        quantize = row_quantize_graph        # the same weights, activations per row
    elif scheme == "float32" and not from_int8:
        raise ValueError(f"{src}: the float32 scheme dequantises int8-dynamic graphs; this bundle's are "
                         f"{', '.join(f'{name}: {value or scheme}' for name, value in done.items())}")
    elif any(done.values()) and not from_int8:
        name, already = next((name, value) for name, value in done.items() if value)
        raise ValueError(f"{src}: {name} is already {already}")
    captured = captured_graphs_to_convert(manifest, scheme)
    converters = {**dict.fromkeys(graphs, quantize), **{name: _quantizer(scheme)[0] for name in captured}}
    if parity and out.resolve() == src.resolve():
        raise ValueError("the output must differ from the bundle: the float32 original is what the copy is measured "
                         "against")
    if out.resolve() == src.resolve():
        check_out_dir(out)   # in place (no parity run): the files are replaced one by one from the staged copy
    else:
        prepare_out_dir(out)   # an earlier bundle there leaves none of its files behind
    names = list(manifest["files"])
    with tempfile.TemporaryDirectory(prefix=f"{scheme}-bundle-") as tmp:
        staged = Path(tmp)
        for name in names:
            (staged / name).parent.mkdir(parents=True, exist_ok=True)
            if name in converters:
                converters[name](src / name, staged / name)
            else:
                shutil.copyfile(src / name, staged / name)
        manifest["quantization"] = {**(manifest.get("quantization") or {}),
                                    **{Path(name).stem: label for name in converters}}
        if version is not None:
            manifest["version"] = version
        written = write_bundle(out, {name: staged / name for name in names}, manifest)
    if not parity:
        return written, None
    default_runs, seconds = family_of_manifest(manifest).quantize_parity
    runs = default_runs if runs is None else runs
    report = compare_bundles(src, out, graphs, runs=runs, seconds=seconds)
    replayed = [compare_bundles(src, out, [name], runs=runs, seconds=seconds, captured=True) for name in captured]
    sizes = {name: ((src / name).stat().st_size, (out / name).stat().st_size) for name in converters}
    card = out / "MODEL_CARD.md"
    if card.is_file():
        text = _quantisation_row(card.read_text(encoding="utf-8"), written)
        source = "the int8 bundle" if from_int8 else "the float32 bundle"
        sections = [card_section(label, report.as_dict(), {name: sizes[name] for name in graphs}, source)]
        sections += [captured_section(label, name, one.as_dict(), sizes[name]) for name, one in zip(captured, replayed)]
        card.write_text("\n\n".join([text.rstrip(), *sections]), encoding="utf-8")
        written = write_bundle(out, {name: out / name for name in names}, written)
    measured = {**report.as_dict(), "scheme": label,
                "bytes": {name: {"float32": a, label: b} for name, (a, b) in sizes.items()}}
    if captured:
        measured["captured"] = {name: one.as_dict() for name, one in zip(captured, replayed)}
    return written, measured


def _quantisation_row(card: str, manifest: dict[str, Any]) -> str:
    """The card's `| quantisation | ... |` row (the GPT family's table has one) made true for the copy."""
    quant = manifest.get("quantization") or {}
    row = "| quantisation | " + "; ".join(f"{key.replace('_', ' ')}: {value or 'float32'}"
                                          for key, value in quant.items()) + " |"
    return re.sub(r"^\| quantisation \|.*\|$", lambda _: row, card, flags=re.MULTILINE)


def card_section(label: str, report: dict[str, Any], sizes: dict[str, tuple[int, int]],
                 source: str = "the float32 bundle") -> str:
    """The model card's section on a quantised copy: what was quantised, how, and its measured parity."""
    lines = [f"## Quantisation: {label} (vs {source})", "",
             f"Quantised graphs: {', '.join(f'`{name}`' for name in sizes)}: {WHAT[label]}. The other graphs (text "
             f"encoder, decoder, any length graph) are {source}'s, as the manifest's `quantization` says (they run "
             "once per request, not per step).", "",
             f"Measured as served, on {report['runs']} seeded one-sentence requests of {report['seconds']:g} s at the "
             f"bundle's default settings (sampling as served): {_agreement(report, source)}; the served joints at "
             f"most {report['max_joint_diff_m']:.3g} m from {source}'s.", ""]
    for name, (before, after) in sizes.items():
        g = report["graphs"][name]
        lines.append(f"- `{name}`: max |{g['output']} diff| {g['max_abs_logit_diff']:.3g} on {source}'s trajectory "
                     f"({g['calls']} calls; its {g['output']} values up to {g['max_abs_logit']:.3g}); "
                     f"{before / 1e6:.1f} -> {after / 1e6:.1f} MB")
    return "\n".join(lines) + "\n"


def _agreement(report: dict[str, Any], source: str) -> str:
    """The card's words for token agreement, or why there is none (a diffusion model's decoder reads features)."""
    if not report["tokens"]:
        return "no tokens to compare (its decoder reads float features)"
    return (f"{report['agreeing']} of {report['tokens']} tokens the same as {source}'s "
            f"({100 * report['agreement']:.1f}%; once one draw differs, the rest of that motion may take another path)")


def captured_section(label: str, name: str, report: dict[str, Any], sizes: tuple[int, int]) -> str:
    """The model card's paragraph on a converted captured graph (served only with T2M_CUDA_GRAPHS on a GPU)."""
    graph = report["graphs"][name]
    return (f"`{name}` (the step T2M_CUDA_GRAPHS replays on a GPU) is {label} too. Served that way (here on the CPU "
            f"provider, which steps it without capturing), {report['runs']} seeded requests of {report['seconds']:g} "
            f"s: {report['agreeing']} of {report['tokens']} tokens the same as the float32 step's "
            f"({100 * report['agreement']:.1f}%); max |logit diff| {graph['max_abs_logit_diff']:.3g} on the float32 "
            f"trajectory, its own cache ({graph['calls']} calls; logits up to {graph['max_abs_logit']:.3g}); "
            f"{sizes[0] / 1e6:.1f} -> {sizes[1] / 1e6:.1f} MB.\n")


def quantize_bundle_gpt(src: str | Path, out: str | Path, version: str | None = None,
                        scheme: str = "int8") -> dict[str, Any]:
    """A GPT-family bundle's quantised copy (quantize_bundle without the parity run); returns the written manifest."""
    manifest = _read_manifest(Path(src))
    if manifest.get("family", "gpt") != "gpt":
        raise ValueError(f"{src}: only GPT-family bundles have gpt_step.onnx (this one is {manifest['family']!r})")
    return quantize_bundle(src, out, version=version, scheme=scheme, parity=False)[0]
