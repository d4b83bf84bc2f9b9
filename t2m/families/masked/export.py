"""Assemble a masked-family bundle (MoMask / MoGenTS token maps) from PyTorch modules or from our training runs.

The GPT family's exporter (t2m.families.gpt.export) stays as it is; this one shares its text sources, its bundle writer
(hash + verify) and its model-card renderer's style. Graphs: text_encoder.onnx, masked.onnx, residual.onnx (more
than one quantiser layer), decoder.onnx over [B, T, C, R] maps, length.onnx (with a length estimator). Parity with
PyTorch (logits, decoded features, identical tokens over a greedy full decode) is measured and written in the card.
"""
from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from t2m.bundle.graphs import branch_graphs
from t2m.export.graphs.encoder import ENCODER_FILE, encoder_card_lines, encoder_parity, write_encoder
from t2m.export.kit.checks import GROSS_PARITY_ERROR, INT8_LABEL, ROW_INT8_LABEL, quantize_in_place, text_int8_line
from t2m.export.kit.text_sources import TextSource
from t2m.export.writing.bundle import (
    check_out_dir,
    max_seconds,
    motion_fields,
    prepare_out_dir,
    render_family_card,
    write_bundle,
)
from t2m.families.masked.export_graphs import (
    MapVQ,
    decode_parity,
    export_joint_decoder,
    export_length,
    export_masked,
    export_residual,
    joint_decoder_parity,
    length_parity,
    map_shape,
    token_graph_int8_report,
    transformer_parity,
    unit_conditions,
)
from t2m.families.masked.length_estimator import LengthEstimator
from t2m.families.masked.masked_transformer import MaskedTransformer
from t2m.families.masked.residual_transformer import ResidualTransformer
from t2m.model.networks.fused_vqvae import FusedVQVAE
from t2m.model.networks.joint_vqvae import JointVQVAE
from t2m.model.networks.vqvae import MotionVQVAE

log = logging.getLogger(__name__)

__all__ = ["INT8_GRAPHS", "MaskedDecoding", "TokenBranch", "check_masked_models", "export_masked_bundle",
           "export_masked_from_runs"]

# graphs that may be int8 (dynamic quantisation, 7-bit weights); the decoder and length graphs stay float32
INT8_GRAPHS = ("text", "masked", "residual")


@dataclass(frozen=True)
class MaskedDecoding:
    """The decoding settings the manifest's `masked` block records (MoMask's defaults; the service's defaults)."""

    steps: int = 10
    guidance: float = 4.0
    residual_guidance: float = 5.0
    top_k: int | None = None
    residual_top_k: int | None = None
    residual_temperature: float | None = None  # None: the request's temperature; MoMask's imports fix it at 1
    temperature: float | None = None  # the mask stage's, fixed (MoGenTS's imports: 1); None: the request's


@dataclass(frozen=True)
class TokenBranch:
    """A further token generator on the same rows (MoGenTS's 1D "aux" tokens beside its 2D map): its models, its
    top-k, and the graphs ``masked_<name>.onnx`` / ``residual_<name>.onnx``; its map joins the primary one along
    the columns before the one decode."""

    name: str
    masked: MaskedTransformer
    residual: ResidualTransformer | None
    top_k: int | None = None
    residual_top_k: int | None = None

    def manifest_entry(self) -> dict[str, Any]:
        c, r = self.masked.config, self.residual
        return {"name": self.name, "columns": c.columns, "codebook_size": c.codebook_size, "top_k": self.top_k,
                "residual_top_k": self.residual_top_k, "mask_id": c.mask_id,
                "pad_id": c.codebook_size if r is None else r.pad_id,
                "residual_mask_class": r is not None and r.mask_id is not None}


def _is_decode(key: str) -> bool:
    """A parity report's full-decode entries: "decode" and "decode_<branch>" (not "decoder")."""
    return key == "decode" or key.startswith("decode_")


@dataclass
class MaskedExportChecks:
    """What export measured against PyTorch (float32)."""

    parity: dict[str, Any] = field(default_factory=dict)
    int8: dict[str, Any] = field(default_factory=dict)
    quantization: dict[str, Any] | None = None   # the import's --quantize report (t2m.export.writing.int8)

    def model_card_section(self) -> str:
        int8 = self._int8_lines()
        if not self.parity:
            return "\n".join(int8)
        p = self.parity
        lines = ["## Export checks (onnxruntime vs PyTorch, float32)", "",
                 f"- masked transformer: max |logit diff| {p['masked']['max_abs_diff']:.2e}"]
        if "residual" in p:
            lines.append(f"- residual transformer: max |logit diff| {p['residual']['max_abs_diff']:.2e}")
        lines.append(f"- decoder: max |feature diff| {p['decoder']['max_abs_diff']:.2e}")
        if "length" in p:
            lines.append(f"- length estimator: max |logit diff| {p['length']['max_abs_diff']:.2e}")
        if "text_encoder" in p:
            lines.append(f"- text encoder: max |feature diff| {p['text_encoder']['max_abs_diff']:.2e}")
        lines += encoder_card_lines(p)
        for key in sorted(p):
            if key.startswith(("masked_", "residual_")):
                role, name = key.split("_", 1)
                lines.append(f"- {role} transformer of branch {name}: max |logit diff| {p[key]['max_abs_diff']:.2e}")
        for key in sorted(k for k in p if _is_decode(k)):
            d, branch = p[key], key.partition("_")[2]
            lines.append(f"- full greedy decode{' of branch ' + branch if branch else ''} (maps {d['shape']}): tokens "
                         f"identical {d['tokens_identical']} ({d['differing_tokens']} differ)")
        return "\n".join([*lines, "", *int8])

    def _int8_lines(self) -> list[str]:
        if not self.int8:
            return []
        lines = ["## int8 dynamic quantisation (vs the float32 graphs)", ""]
        if "text_encoder" in self.int8:
            lines.append(text_int8_line(self.int8["text_encoder"]))
        for key in ("masked", "residual"):
            if key in self.int8:
                r = self.int8[key]
                lines.append(f"- {key} transformer: max |logit diff| {r['max_abs_logit_diff']:.3f} (logits up to "
                             f"{r['max_abs_logit']:.1f}); {r['fp32_ms']:.1f} -> {r['int8_ms']:.1f} ms per forward of a "
                             f"guidance pair x {r['rows']} rows; {r['fp32_bytes'] / 1e6:.1f} -> "
                             f"{r['int8_bytes'] / 1e6:.1f} MB")
        if "decode" in self.int8:
            d = self.int8["decode"]
            total = int(np.prod(d["shape"]))
            lines.append(f"- full greedy decode with the int8 graphs vs PyTorch (maps {d['shape']}, unit-norm text "
                         f"features): {total - d['differing_tokens']} of {total} tokens identical")
        float32 = [name for name in ("text encoder", "masked", "residual")
                   if name.split()[0] not in self.int8 and f"{name.split()[0]}_encoder" not in self.int8]
        lines += [f"- float32: {', '.join(float32 + ['decoder', 'length'])}", ""]
        return lines


def _check_generator(role: str, masked: MaskedTransformer, residual: ResidualTransformer | None, codebook: int,
                     columns: int, layers: int) -> None:
    """One generator fits its part of the VQ's map: codebook, columns, layers, one text dim."""
    c = masked.config
    if (c.codebook_size, c.columns) != (codebook, columns):
        raise ValueError(f"the {role}masked transformer has {c.codebook_size} codes x {c.columns} columns, the VQ "
                         f"{codebook} x {columns}")
    if layers > 1 and residual is None:
        raise ValueError(f"the VQ has {layers} quantiser layers: a {role}residual transformer is needed")
    if residual is not None:
        r = residual.config
        if layers == 1:
            raise ValueError("the VQ has one quantiser layer: a residual transformer has nothing to predict")
        if (r.codebook_size, r.columns, r.residual_layers) != (codebook, columns, layers):
            raise ValueError(f"the {role}residual transformer has {r.codebook_size} codes x {r.columns} columns x "
                             f"{r.residual_layers} layers, the VQ {codebook} x {columns} x {layers}")
        if r.text_dim != c.text_dim:
            raise ValueError(f"text dims differ: masked {c.text_dim}, residual {r.text_dim}")


def check_masked_models(vq: MapVQ, masked: MaskedTransformer, residual: ResidualTransformer | None,
                        length: LengthEstimator | None, branches: Sequence[TokenBranch] = ()) -> None:
    """The modules fit together: codebook, columns and layers of the VQ (the fused VQ: the 2D map for the primary
    generator, its 1D tokens for one branch), one text dim, one max_tokens."""
    columns, layers = map_shape(vq)
    c = masked.config
    branch_codebooks = [vq.config.nb_code1d] if isinstance(vq, FusedVQVAE) else []
    if len(branches) != len(branch_codebooks):
        raise ValueError(f"the VQ's map holds {len(branch_codebooks) + 1} generator(s)' tokens, got "
                         f"{len(branches) + 1}")
    primary = columns - sum(branch.masked.config.columns for branch in branches)
    _check_generator("", masked, residual, vq.config.nb_code, primary, layers)
    for branch, codebook in zip(branches, branch_codebooks):
        _check_generator(f"{branch.name} ", branch.masked, branch.residual, codebook, branch.masked.config.columns,
                         layers)
        if branch.masked.config.text_dim != c.text_dim:
            raise ValueError(f"text dims differ: masked {c.text_dim}, {branch.name} {branch.masked.config.text_dim}")
    if length is not None:
        if length.config.text_dim != c.text_dim:
            raise ValueError(f"text dims differ: masked {c.text_dim}, length estimator {length.config.text_dim}")
        if length.config.max_tokens != c.max_tokens:
            raise ValueError(f"max_tokens differ: masked {c.max_tokens}, length estimator {length.config.max_tokens}")


def _residual_temperature(masked: Mapping[str, Any]) -> str:
    value = masked.get("residual_temperature")
    return "" if value is None else f", temperature {value:g}"


def _branches(branches: list[dict[str, Any]]) -> str:
    return "; ".join(f"{b['name']}: codebook {b['codebook_size']}, {b['columns']} column(s), top-k {b['top_k']} "
                     f"(residual {b['residual_top_k']}), its map joined to the decoder's columns"
                     for b in branches)


def render_masked_model_card(manifest: Mapping[str, Any], notes: str = "") -> str:
    """MODEL_CARD.md from the manifest's facts (+ the export checks and free-form notes)."""
    m = manifest["masked"]
    rows = [("tokens", f"codebook {manifest['codebook_size']}, {m['columns']} columns, residual layers "
                       f"{manifest['residual_layers']}, at most {manifest['max_tokens']} rows "
                       f"({max_seconds(manifest):.1f} s)"),
            ("decoding", f"{m['steps']} re-masking steps, guidance {m['guidance']} (residual "
                         f"{m['residual_guidance']}), top-k {m['top_k']} (residual {m['residual_top_k']}"
                         f"{_residual_temperature(m)}); length estimator {'yes' if m['length_estimator'] else 'no'}"),
            *([("further generators", _branches(m["branches"]))] if m.get("branches") else [])]
    return render_family_card(manifest, "Text-to-motion model bundle for t2m-service (masked family: VQ decoder + "
                                        "masked and residual transformers over token maps + text encoder, ONNX).",
                              rows, notes)


def _parity(out_dir: Path, vq: MapVQ, masked: MaskedTransformer, residual: ResidualTransformer | None,
            length: LengthEstimator | None, text_source: TextSource, mean: np.ndarray, std: np.ndarray,
            decoding: MaskedDecoding, branches: Sequence[TokenBranch]) -> dict[str, Any]:
    from t2m.export.kit.parity import text_parity

    report: dict[str, Any] = {"masked": asdict(transformer_parity(masked, out_dir / "masked.onnx")),
                              "decoder": asdict(joint_decoder_parity(vq, mean, std, out_dir / "decoder.onnx"))}
    if residual is not None:
        report["residual"] = asdict(transformer_parity(residual, out_dir / "residual.onnx"))
    if length is not None:
        report["length"] = asdict(length_parity(length, out_dir / "length.onnx"))
    if text_source.encoder is not None:
        report["text_encoder"] = asdict(text_parity(text_source.encoder, out_dir / "text_encoder.onnx",
                                                    out_dir / "tokenizer.json"))
    rows = [min(masked.config.max_tokens, 6), min(masked.config.max_tokens, 3)]
    generators = [("", masked, residual, ("masked.onnx", "residual.onnx"))]
    generators += [(f"_{b.name}", b.masked, b.residual, branch_graphs(b.name)) for b in branches]
    for suffix, m, r, (m_file, r_file) in generators:
        if suffix:
            report[f"masked{suffix}"] = asdict(transformer_parity(m, out_dir / m_file))
            if r is not None:
                report[f"residual{suffix}"] = asdict(transformer_parity(r, out_dir / r_file))
        report[f"decode{suffix}"] = asdict(decode_parity(
            m, r, out_dir / m_file, None if r is None else out_dir / r_file, rows, steps=decoding.steps,
            guidance=decoding.guidance, residual_guidance=decoding.residual_guidance))
    worst = {key: value["max_abs_diff"] for key, value in report.items() if "max_abs_diff" in value}
    broken = {key: diff for key, diff in worst.items() if not diff <= GROSS_PARITY_ERROR}
    if broken:
        raise ValueError(f"exported graphs differ from PyTorch by more than {GROSS_PARITY_ERROR}: {broken}")
    for key in (k for k in report if _is_decode(k) and not report[k]["tokens_identical"]):
        log.warning("masked graphs: greedy tokens differ from PyTorch's (near-tie logits?): %s", report[key])
    return report


def export_masked_bundle(
    out_dir: str | Path, *, vq: MapVQ, masked: MaskedTransformer,
    residual: ResidualTransformer | None, length: LengthEstimator | None, mean: np.ndarray, std: np.ndarray,
    text_source: TextSource, name: str, version: str, training_data: Mapping[str, str], license: str,
    decoding: MaskedDecoding = MaskedDecoding(), unconditional_branch: bool = True, notes: str = "",
    check_parity: bool = True, int8: frozenset[str] = frozenset(), branches: Sequence[TokenBranch] = (),
    encoder: bool = True,
) -> tuple[dict[str, Any], MaskedExportChecks]:
    """Export, check against PyTorch, write and verify a masked bundle; returns (manifest, checks).

    ``int8`` names graphs of INT8_GRAPHS to quantise after the float32 parity checks; each one's price is measured
    (text: cosine to the float32 features; token graphs: logit difference, speed, and a greedy full decode with the
    int8 graphs against PyTorch); a bundle with branches keeps its token graphs float32. ``branches``: further
    generators on the same rows (the manifest's ``masked.branches``; MoGenTS)."""
    unknown = set(int8) - set(INT8_GRAPHS)
    if unknown:
        raise ValueError(f"int8: {', '.join(sorted(unknown))} not among {', '.join(INT8_GRAPHS)}")
    if "residual" in int8 and residual is None:
        raise ValueError("int8: 'residual' given but there is no residual transformer")
    if {"masked", "residual"} & set(int8) and branches:
        raise ValueError("int8: token graphs of a bundle with branches stay float32 (only 'text')")
    check_masked_models(vq, masked, residual, length, branches)
    limits = [(key, value, masked.config.codebook_size) for key, value in
              (("top_k", decoding.top_k), ("residual_top_k", decoding.residual_top_k))]
    limits += [(f"{b.name} {key}", value, b.masked.config.codebook_size) for b in branches
               for key, value in (("top_k", b.top_k), ("residual_top_k", b.residual_top_k))]
    for key, value, size in limits:
        if value is not None and not 1 <= value <= size:
            raise ValueError(f"{key} must be null or 1..{size}, got {value}")
    for key, temperature in (("residual_temperature", decoding.residual_temperature),
                             ("temperature", decoding.temperature)):
        if temperature is not None and not temperature > 0:
            raise ValueError(f"{key} must be null or > 0, got {temperature}")
    check_out_dir(out_dir)
    out_dir = prepare_out_dir(out_dir)
    for module in (vq, masked, residual, length, *(m for b in branches for m in (b.masked, b.residual))):
        if module is not None:
            module.eval()
    log.info("exporting the text encoder")
    text_entry = text_source.write(out_dir)
    if text_entry["dim"] != masked.config.text_dim:
        raise ValueError(f"text encoder dim {text_entry['dim']} != masked transformer text_dim "
                         f"{masked.config.text_dim}")
    names = ["text_encoder.onnx", "tokenizer.json", "masked.onnx"]
    export_masked(masked, out_dir / "masked.onnx")
    if residual is not None:
        export_residual(residual, out_dir / "residual.onnx")
        names.append("residual.onnx")
    for branch in branches:
        masked_file, residual_file = branch_graphs(branch.name)
        export_masked(branch.masked, out_dir / masked_file)
        names.append(masked_file)
        if branch.residual is not None:
            export_residual(branch.residual, out_dir / residual_file)
            names.append(residual_file)
    if length is not None:
        export_length(length, out_dir / "length.onnx")
        names.append("length.onnx")
    export_joint_decoder(vq, mean, std, out_dir / "decoder.onnx")
    names += write_encoder(vq, out_dir, 4) if encoder and not branches else []   # the decoder's maps [B, T, C, R]
    np.save(out_dir / "mean.npy", np.asarray(mean, dtype=np.float32))
    np.save(out_dir / "std.npy", np.asarray(std, dtype=np.float32))
    layers = map_shape(vq)[1]
    c = masked.config
    manifest: dict[str, Any] = {
        "format_version": 1, "family": "masked", "name": name, "version": version,
        **motion_fields(vq.config.feat_dim, vq.config.frames_per_token, c.max_tokens),
        "codebook_size": c.codebook_size, "residual_layers": layers,
        "masked": {"columns": c.columns, "steps": decoding.steps, "guidance": float(decoding.guidance),
                   "residual_guidance": float(decoding.residual_guidance), "top_k": decoding.top_k,
                   "residual_top_k": decoding.residual_top_k, "mask_id": c.mask_id,
                   "pad_id": c.codebook_size if residual is None else residual.pad_id,
                   "unconditional_branch": bool(unconditional_branch), "length_estimator": length is not None,
                   **({} if decoding.residual_temperature is None
                      else {"residual_temperature": float(decoding.residual_temperature)}),
                   **({} if decoding.temperature is None else {"temperature": float(decoding.temperature)}),
                   **({"residual_mask_class": True} if residual is not None and residual.mask_id is not None
                      else {}),
                   **({"branches": [branch.manifest_entry() for branch in branches]} if branches else {})},
        "text_encoder": text_entry, "training_data": dict(training_data), "license": license,
        "quantization": {"text_encoder": None},
    }
    checks = MaskedExportChecks()
    if check_parity:
        log.info("checking onnxruntime against PyTorch (float32)")
        checks.parity = _parity(out_dir, vq, masked, residual, length, text_source, mean, std, decoding, branches)
        if ENCODER_FILE in names and not isinstance(vq, FusedVQVAE):
            checks.parity["encoder"] = encoder_parity(vq, out_dir / ENCODER_FILE, 4)
    _quantize(out_dir, int8, masked, residual, manifest, checks, decoding)
    card_notes = "\n\n".join(part for part in (checks.model_card_section(), notes.strip()) if part)
    (out_dir / "MODEL_CARD.md").write_text(render_masked_model_card(manifest, card_notes), encoding="utf-8")
    names += ["decoder.onnx", "mean.npy", "std.npy", "MODEL_CARD.md"]
    return write_bundle(out_dir, {name: out_dir / name for name in names}, manifest), checks


def _token_graph_report(model: MaskedTransformer | ResidualTransformer) -> Callable[[Path, Path], dict[str, Any]]:
    return lambda fp32, int8: asdict(token_graph_int8_report(model, fp32, int8))


def _quantize(out_dir: Path, int8: frozenset[str], masked: MaskedTransformer, residual: ResidualTransformer | None,
              manifest: dict[str, Any], checks: MaskedExportChecks, decoding: MaskedDecoding) -> None:
    """Replace the chosen graphs by int8 ones, measuring each against its float32 export."""
    from t2m.export.writing.quantize import text_int8_report

    if "text" in int8:
        checks.int8["text_encoder"] = quantize_in_place(
            out_dir / "text_encoder.onnx",
            lambda fp32, q: asdict(text_int8_report(fp32, q, out_dir / "tokenizer.json")))
        manifest["quantization"]["text_encoder"] = INT8_LABEL
    models: dict[str, MaskedTransformer | ResidualTransformer | None] = {"masked": masked, "residual": residual}
    for key, model in models.items():
        if key in int8 and model is not None:
            checks.int8[key] = quantize_in_place(out_dir / f"{key}.onnx", _token_graph_report(model), per_row=True)
            manifest["quantization"][key] = ROW_INT8_LABEL
    if {"masked", "residual"} & int8:
        rows = masked.config.max_tokens
        checks.int8["decode"] = asdict(decode_parity(
            masked, residual, out_dir / "masked.onnx", None if residual is None else out_dir / "residual.onnx",
            [rows, rows // 2, min(rows, 10)], steps=decoding.steps, guidance=decoding.guidance,
            residual_guidance=decoding.residual_guidance, cond=unit_conditions(3, masked.config.text_dim)))


# ------------------------------------------------------------------------------------------- from our runs

def _load_vq(vq_run: Path) -> JointVQVAE | MotionVQVAE:
    from t2m.model.training.checkpoint import load_run, read_run_config

    kind = read_run_config(vq_run)["kind"]
    if kind == "joint_vq":
        return load_run(vq_run, kind, JointVQVAE)
    if kind == "vq":
        return load_run(vq_run, kind, MotionVQVAE)
    raise ValueError(f"{vq_run}/config.json: --vq must be a joint_vq or vq run, found {kind!r}")


def export_masked_from_runs(
    vq_run: str | Path, masked_run: str | Path, out_dir: str | Path, *, residual_run: str | Path | None = None,
    length_run: str | Path | None = None, name: str | None = None, version: str = "0.1.0",
    model_card: str | Path | None = None, data_summary: str | Path | None = None,
    decoding: MaskedDecoding = MaskedDecoding(), check_parity: bool = True, text_source: TextSource | None = None,
    int8: frozenset[str] = frozenset(),
) -> tuple[dict[str, Any], MaskedExportChecks]:
    """A verified masked bundle from a joint_vq (or 1D vq) run, a masked run, a residual run (when the VQ has more
    than one layer) and an optional length run. ``text_source`` replaces building the run's text encoder (tests)."""
    from t2m.export.kit.runs import normalisation as _normalisation
    from t2m.export.kit.runs import run_training_data
    from t2m.export.kit.text_sources import recorded_text_source
    from t2m.model.training.checkpoint import check_trained_on, load_run, read_run_config

    vq_run, masked_run = Path(vq_run), Path(masked_run)
    runs = {"masked": masked_run, "residual": residual_run, "length": length_run}
    records = {key: read_run_config(run) for key, run in runs.items() if run is not None}
    for key, record in records.items():
        if record["kind"] != key:
            raise ValueError(f"{runs[key]}/config.json: expected a {key} checkpoint, found {record['kind']!r}")
    vq_record = read_run_config(vq_run)
    vq = _load_vq(vq_run)
    for key in ("masked", "residual"):
        if key in records:
            check_trained_on(str(runs[key]), vq_run)
    masked = load_run(masked_run, "masked", MaskedTransformer)
    residual = None if residual_run is None else load_run(residual_run, "residual", ResidualTransformer)
    length = None if length_run is None else load_run(length_run, "length", LengthEstimator)
    check_masked_models(vq, masked, residual, length)
    masked_data = records["masked"].get("data", {})
    kind, make_text_source = recorded_text_source(masked_run, masked_data, text_source)
    training_data = run_training_data(masked_run, masked_data, vq_record, data_summary)
    cond_drop = float((masked_data.get("training") or {}).get("cond_drop", 0.0))
    mean, std = _normalisation(vq_run, vq_record)
    lines = [f"- VQ run: `{vq_run.name}` (step {vq_record.get('step')})",
             f"- masked run: `{masked_run.name}` (step {records['masked'].get('step')}), condition dropout {cond_drop}"]
    lines += [f"- {key} run: `{Path(str(runs[key])).name}` (step {records[key].get('step')})"
              for key in ("residual", "length") if key in records]
    notes = "## Provenance\n\n" + "\n".join(lines) + "\n"
    if model_card:
        notes += "\n" + Path(model_card).read_text(encoding="utf-8")
    return export_masked_bundle(
        out_dir, vq=vq, masked=masked, residual=residual, length=length, mean=mean, std=std,
        text_source=make_text_source(),
        name=name or f"t2m-{training_data['name']}-masked-{kind}", version=version, training_data=training_data,
        license=training_data["license"], decoding=decoding, unconditional_branch=cond_drop > 0, notes=notes,
        check_parity=check_parity, int8=int8)
