"""Assemble a masked-family bundle (MoMask / MoGenTS token maps) from PyTorch modules or from our training runs.

The GPT family's exporter (t2m.export.exporter) stays as it is; this one shares its text sources, its bundle writer
(hash + verify) and its model-card renderer's style. Graphs: text_encoder.onnx, masked.onnx, residual.onnx (more
than one quantiser layer), decoder.onnx over [B, T, C, R] maps, length.onnx (with a length estimator). Parity with
PyTorch (logits, decoded features, identical tokens over a greedy full decode) is measured and written in the card.
"""
from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from t2m.export.bundle import (
    check_out_dir,
    max_seconds,
    motion_fields,
    prepare_out_dir,
    render_family_card,
    write_bundle,
)
from t2m.export.exporter import GROSS_PARITY_ERROR, TextSource
from t2m.export.onnx_masked import (
    decode_parity,
    export_joint_decoder,
    export_length,
    export_masked,
    export_residual,
    joint_decoder_parity,
    length_parity,
    map_shape,
    transformer_parity,
)
from t2m.model.networks.joint_vqvae import JointVQVAE
from t2m.model.networks.length_estimator import LengthEstimator
from t2m.model.networks.masked_transformer import MaskedTransformer
from t2m.model.networks.residual_transformer import ResidualTransformer
from t2m.model.networks.vqvae import MotionVQVAE

log = logging.getLogger(__name__)

__all__ = ["MaskedDecoding", "check_masked_models", "export_masked_bundle", "export_masked_from_runs"]


@dataclass(frozen=True)
class MaskedDecoding:
    """The decoding settings the manifest's `masked` block records (MoMask's defaults; the service's defaults)."""

    steps: int = 10
    guidance: float = 4.0
    residual_guidance: float = 5.0
    top_k: int | None = None
    residual_top_k: int | None = None


@dataclass
class MaskedExportChecks:
    """What export measured against PyTorch (float32)."""

    parity: dict[str, Any] = field(default_factory=dict)

    def model_card_section(self) -> str:
        if not self.parity:
            return ""
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
        d = p["decode"]
        lines += [f"- full greedy decode (maps {d['shape']}): tokens identical {d['tokens_identical']}"
                  f" ({d['differing_tokens']} differ)", ""]
        return "\n".join(lines)


def check_masked_models(vq: JointVQVAE | MotionVQVAE, masked: MaskedTransformer,
                        residual: ResidualTransformer | None, length: LengthEstimator | None) -> None:
    """The modules fit together: codebook, columns and layers of the VQ, one text dim, one max_tokens."""
    columns, layers = map_shape(vq)
    c = masked.config
    if (c.codebook_size, c.columns) != (vq.config.nb_code, columns):
        raise ValueError(f"the masked transformer has {c.codebook_size} codes x {c.columns} columns, the VQ "
                         f"{vq.config.nb_code} x {columns}")
    if layers > 1 and residual is None:
        raise ValueError(f"the VQ has {layers} quantiser layers: a residual transformer is needed")
    if residual is not None:
        r = residual.config
        if layers == 1:
            raise ValueError("the VQ has one quantiser layer: a residual transformer has nothing to predict")
        if (r.codebook_size, r.columns, r.residual_layers) != (vq.config.nb_code, columns, layers):
            raise ValueError(f"the residual transformer has {r.codebook_size} codes x {r.columns} columns x "
                             f"{r.residual_layers} layers, the VQ {vq.config.nb_code} x {columns} x {layers}")
        if r.text_dim != c.text_dim:
            raise ValueError(f"text dims differ: masked {c.text_dim}, residual {r.text_dim}")
    if length is not None:
        if length.config.text_dim != c.text_dim:
            raise ValueError(f"text dims differ: masked {c.text_dim}, length estimator {length.config.text_dim}")
        if length.config.max_tokens != c.max_tokens:
            raise ValueError(f"max_tokens differ: masked {c.max_tokens}, length estimator {length.config.max_tokens}")


def render_masked_model_card(manifest: Mapping[str, Any], notes: str = "") -> str:
    """MODEL_CARD.md from the manifest's facts (+ the export checks and free-form notes)."""
    m = manifest["masked"]
    rows = [("tokens", f"codebook {manifest['codebook_size']}, {m['columns']} columns, residual layers "
                       f"{manifest['residual_layers']}, at most {manifest['max_tokens']} rows "
                       f"({max_seconds(manifest):.1f} s)"),
            ("decoding", f"{m['steps']} re-masking steps, guidance {m['guidance']} (residual "
                         f"{m['residual_guidance']}), top-k {m['top_k']} (residual {m['residual_top_k']}); length "
                         f"estimator {'yes' if m['length_estimator'] else 'no'}")]
    return render_family_card(manifest, "Text-to-motion model bundle for t2m-service (masked family: VQ decoder + "
                                        "masked and residual transformers over token maps + text encoder, ONNX).",
                              rows, notes)


def _parity(out_dir: Path, vq: JointVQVAE | MotionVQVAE, masked: MaskedTransformer,
            residual: ResidualTransformer | None, length: LengthEstimator | None, text_source: TextSource,
            mean: np.ndarray, std: np.ndarray, decoding: MaskedDecoding) -> dict[str, Any]:
    from t2m.export.parity import text_parity

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
    report["decode"] = asdict(decode_parity(
        masked, residual, out_dir / "masked.onnx", None if residual is None else out_dir / "residual.onnx", rows,
        steps=decoding.steps, guidance=decoding.guidance, residual_guidance=decoding.residual_guidance))
    worst = {key: value["max_abs_diff"] for key, value in report.items() if "max_abs_diff" in value}
    broken = {key: diff for key, diff in worst.items() if not diff <= GROSS_PARITY_ERROR}
    if broken:
        raise ValueError(f"exported graphs differ from PyTorch by more than {GROSS_PARITY_ERROR}: {broken}")
    if not report["decode"]["tokens_identical"]:
        log.warning("masked graphs: greedy tokens differ from PyTorch's (near-tie logits?): %s", report["decode"])
    return report


def export_masked_bundle(
    out_dir: str | Path, *, vq: JointVQVAE | MotionVQVAE, masked: MaskedTransformer,
    residual: ResidualTransformer | None, length: LengthEstimator | None, mean: np.ndarray, std: np.ndarray,
    text_source: TextSource, name: str, version: str, training_data: Mapping[str, str], license: str,
    decoding: MaskedDecoding = MaskedDecoding(), unconditional_branch: bool = True, notes: str = "",
    check_parity: bool = True,
) -> tuple[dict[str, Any], MaskedExportChecks]:
    """Export, check against PyTorch, write and verify a masked bundle; returns (manifest, checks)."""
    check_masked_models(vq, masked, residual, length)
    for key, value in (("top_k", decoding.top_k), ("residual_top_k", decoding.residual_top_k)):
        if value is not None and not 1 <= value <= masked.config.codebook_size:
            raise ValueError(f"{key} must be null or 1..{masked.config.codebook_size}, got {value}")
    check_out_dir(out_dir)
    out_dir = prepare_out_dir(out_dir)
    for module in (vq, masked, residual, length):
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
    if length is not None:
        export_length(length, out_dir / "length.onnx")
        names.append("length.onnx")
    export_joint_decoder(vq, mean, std, out_dir / "decoder.onnx")
    np.save(out_dir / "mean.npy", np.asarray(mean, dtype=np.float32))
    np.save(out_dir / "std.npy", np.asarray(std, dtype=np.float32))
    columns, layers = map_shape(vq)
    c = masked.config
    manifest: dict[str, Any] = {
        "format_version": 1, "family": "masked", "name": name, "version": version,
        **motion_fields(vq.config.feat_dim, vq.config.frames_per_token, c.max_tokens),
        "codebook_size": c.codebook_size, "residual_layers": layers,
        "masked": {"columns": columns, "steps": decoding.steps, "guidance": float(decoding.guidance),
                   "residual_guidance": float(decoding.residual_guidance), "top_k": decoding.top_k,
                   "residual_top_k": decoding.residual_top_k, "mask_id": c.mask_id, "pad_id": c.codebook_size,
                   "unconditional_branch": bool(unconditional_branch), "length_estimator": length is not None},
        "text_encoder": text_entry, "training_data": dict(training_data), "license": license,
        "quantization": {"text_encoder": None},
    }
    checks = MaskedExportChecks()
    if check_parity:
        log.info("checking onnxruntime against PyTorch (float32)")
        checks.parity = _parity(out_dir, vq, masked, residual, length, text_source, mean, std, decoding)
    card_notes = "\n\n".join(part for part in (checks.model_card_section(), notes.strip()) if part)
    (out_dir / "MODEL_CARD.md").write_text(render_masked_model_card(manifest, card_notes), encoding="utf-8")
    names += ["decoder.onnx", "mean.npy", "std.npy", "MODEL_CARD.md"]
    return write_bundle(out_dir, {name: out_dir / name for name in names}, manifest), checks


# ------------------------------------------------------------------------------------------- from our runs

def _load_vq(vq_run: Path) -> JointVQVAE | MotionVQVAE:
    from t2m.model.evaluation.masked_family import load_run
    from t2m.model.training.checkpoint import read_run_config

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
) -> tuple[dict[str, Any], MaskedExportChecks]:
    """A verified masked bundle from a joint_vq (or 1D vq) run, a masked run, a residual run (when the VQ has more
    than one layer) and an optional length run. ``text_source`` replaces building the run's text encoder (tests)."""
    from t2m.export.exporter import _normalisation, recorded_text_source, run_training_data
    from t2m.model.evaluation.masked_family import check_trained_on, load_run
    from t2m.model.training.checkpoint import read_run_config

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
        check_parity=check_parity)
