"""Assemble a T2M-HiFiGPT bundle (`"family": "hifigpt"`) from PyTorch modules or from our training runs.

Graphs (t2m.families.hifigpt.export_graphs): text_encoder.onnx, temporal_step.onnx and residual_step.onnx (each with
its KV
cache), decoder.onnx over [B, T, R] codes. Before it is written the bundle is checked against PyTorch: the decoder on
codes with unused depths, the text graph, and a seeded guided rollout of the shared loop with the graphs and with the
modules (identical codes and stops, largest differences of the context, stop and code logits); the model card records
the figures. It shares the bundle writer (hash + verify), the text sources and the card layout with the other
families.
"""
from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from t2m.export.graphs.decoder import export_decoder
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
from t2m.families.hifigpt.export_graphs import export_residual_step, export_temporal_step, rollout_parity
from t2m.families.hifigpt.network import HiFiGPT, check_fits_vq, vq_codebooks
from t2m.model.networks.vqvae import MotionVQVAE

log = logging.getLogger(__name__)

__all__ = ["check_hifigpt_models", "export_hifigpt_bundle", "export_hifigpt_from_runs"]

GRAPHS = ("text_encoder.onnx", "tokenizer.json", "temporal_step.onnx", "residual_step.onnx", "decoder.onnx")
# graphs that may be int8 (dynamic quantisation, 7-bit weights): --int8 name -> the graph's manifest key; the decoder
# stays float32 (a small share of the bytes, and the motion's last word)
INT8_GRAPHS = {"text": "text_encoder", "temporal": "temporal_step", "residual": "residual_step"}


@dataclass
class HiFiGPTExportChecks:
    """What export measured against PyTorch (float32)."""

    parity: dict[str, Any] = field(default_factory=dict)
    int8: dict[str, Any] = field(default_factory=dict)

    def model_card_section(self) -> str:
        return "\n".join(part for part in (self._parity_section(), self._int8_section()) if part)

    def _int8_section(self) -> str:
        if not self.int8:
            return ""
        lines = ["## int8 dynamic quantisation (vs the float32 graphs)", ""]
        if "text_encoder" in self.int8:
            lines.append(text_int8_line(self.int8["text_encoder"]))
        if "rollout" in self.int8:
            r = self.int8["rollout"]
            graphs = " and ".join(f"{key}.onnx ({self.int8[key]['fp32_bytes'] / 1e6:.1f} -> "
                                  f"{self.int8[key]['int8_bytes'] / 1e6:.1f} MB)"
                                  for key in ("temporal_step", "residual_step") if key in self.int8)
            stops = "identical" if r["steps_identical"] else "differ"
            lines.append(f"- {graphs}: the seeded guided rollout of the export checks, int8 graphs vs PyTorch: "
                         f"{r['differing_codes']} codes differ, stops {stops}"
                         f" (steps {r['steps']}); max |diff| context {r['max_abs_context_diff']:.2e}, stop logit "
                         f"{r['max_abs_stop_diff']:.2e}, code logits {r['max_abs_logit_diff']:.2e}")
        return "\n".join(lines + [""])

    def _parity_section(self) -> str:
        if not self.parity:
            return ""
        r, d = self.parity["rollout"], self.parity["decoder"]
        lines = ["## Export checks (onnxruntime vs PyTorch, float32)", "",
                 f"- seeded guided rollout (guidance {r['guidance']}, temperature 1, {r['segments']} segments: two of "
                 f"fixed length, two ending on the stop head; steps {r['steps']}): codes and stops identical "
                 f"{r['codes_identical']} ({r['differing_codes']} codes differ); max |diff| context "
                 f"{r['max_abs_context_diff']:.2e}, stop logit {r['max_abs_stop_diff']:.2e}, code logits "
                 f"{r['max_abs_logit_diff']:.2e}",
                 f"- decoder ([B, T, R] codes, some depths -1): max |feature diff| {d['max_abs_diff']:.2e}"]
        if "text_encoder" in self.parity:
            lines.append(f"- text encoder: max |feature diff| {self.parity['text_encoder']['max_abs_diff']:.2e}")
        return "\n".join(lines + encoder_card_lines(self.parity) + [""])


def check_hifigpt_models(vq: MotionVQVAE, model: HiFiGPT) -> None:
    """The GPT was built for this VQ: a residual VQ of its codebook size, depth, code_dim and codebooks."""
    if vq.config.quantizer != "residual":
        raise ValueError(f"a hifigpt bundle needs a residual VQ (its decoder takes [B, T, R] codes), got quantizer "
                         f"{vq.config.quantizer!r}")
    check_fits_vq(model.config, vq.config.to_dict())
    if not np.allclose(vq_codebooks(vq).numpy(), model.codebooks.numpy(), atol=1e-6):
        log.warning("the HiFiGPT's codebooks differ from the VQ's: its inputs were not the codes' vectors")


def render_hifigpt_model_card(manifest: Mapping[str, Any], notes: str = "") -> str:
    h = manifest["hifigpt"]
    rows = [("codes", f"codebook {manifest['codebook_size']}, residual depth {manifest['residual_layers']}, at most "
                      f"{manifest['max_tokens']} time steps ({max_seconds(manifest):.1f} s)"),
            ("double-tier GPT", f"temporal {h['n_layer_temporal']} + residual {h['n_layer_residual']} layers, "
                                f"{h['n_head']} heads x {h['head_dim']}, length conditioning "
                                f"{'yes' if h['length_conditioning'] else 'no'}"),
            ("guidance", f"on code and stop logits; trained unconditional branch: "
                         f"{'yes' if h['unconditional_branch'] else 'no'}; default scale {h['default_guidance']}")]
    return render_family_card(manifest, "Text-to-motion model bundle for t2m-service (T2M-HiFiGPT: residual VQ "
                                        "decoder + temporal and residual GPT step graphs with KV caches + text "
                                        "encoder, ONNX).", rows, notes)


def _parity(out_dir: Path, vq: MotionVQVAE, model: HiFiGPT, text_source: TextSource, guidance: float
            ) -> dict[str, Any]:
    from t2m.export.kit.parity import decoder_parity, text_parity

    report: dict[str, Any] = {
        "rollout": asdict(rollout_parity(model, out_dir / "temporal_step.onnx", out_dir / "residual_step.onnx",
                                         guidance=guidance)),
        "decoder": asdict(decoder_parity(vq, np.load(out_dir / "mean.npy"), np.load(out_dir / "std.npy"),
                                         out_dir / "decoder.onnx"))}
    if text_source.encoder is not None:
        report["text_encoder"] = asdict(text_parity(text_source.encoder, out_dir / "text_encoder.onnx",
                                                    out_dir / "tokenizer.json"))
    r = report["rollout"]
    worst = {"temporal_step": max(r["max_abs_context_diff"], r["max_abs_stop_diff"]),
             "residual_step": r["max_abs_logit_diff"], "decoder": report["decoder"]["max_abs_diff"]}
    if "text_encoder" in report:
        worst["text_encoder"] = report["text_encoder"]["max_abs_diff"]
    broken = {key: diff for key, diff in worst.items() if not diff <= GROSS_PARITY_ERROR}
    if broken:
        raise ValueError(f"exported graphs differ from PyTorch by more than {GROSS_PARITY_ERROR}: {broken}")
    if not r["codes_identical"]:
        log.warning("hifigpt graphs: the rollout's codes differ from PyTorch's (near-tie draws?): %s", r)
    return report


def export_hifigpt_bundle(
    out_dir: str | Path, *, vq: MotionVQVAE, model: HiFiGPT, mean: np.ndarray, std: np.ndarray,
    text_source: TextSource, name: str, version: str, training_data: Mapping[str, str], license: str,
    unconditional_branch: bool = True, default_guidance: float = 3.0, notes: str = "", check_parity: bool = True,
    int8: frozenset[str] = frozenset(), encoder: bool = True,
) -> tuple[dict[str, Any], HiFiGPTExportChecks]:
    """Export, check against PyTorch, write and verify a hifigpt bundle; returns (manifest, checks). ``int8`` names
    graphs of INT8_GRAPHS to quantise after the float32 checks (each one's price measured into the card)."""
    unknown = set(int8) - set(INT8_GRAPHS)
    if unknown:
        raise ValueError(f"int8: {', '.join(sorted(unknown))} not among {', '.join(INT8_GRAPHS)}")
    check_hifigpt_models(vq, model)
    if default_guidance < 0:
        raise ValueError(f"default guidance must be >= 0, got {default_guidance}")
    check_out_dir(out_dir)
    out_dir = prepare_out_dir(out_dir)
    vq, model = vq.eval(), model.eval()
    log.info("exporting the text encoder")
    text_entry = text_source.write(out_dir)
    c = model.config
    if text_entry["dim"] != c.text_dim:
        raise ValueError(f"text encoder dim {text_entry['dim']} != HiFiGPT text_dim {c.text_dim}")
    log.info("exporting the temporal and residual step graphs and the decoder")
    export_temporal_step(model, out_dir / "temporal_step.onnx")
    export_residual_step(model, out_dir / "residual_step.onnx")
    export_decoder(vq, mean, std, out_dir / "decoder.onnx")
    encoders = write_encoder(vq, out_dir, 3) if encoder else []   # the decoder's codes: [B, T, R]
    np.save(out_dir / "mean.npy", np.asarray(mean, dtype=np.float32))
    np.save(out_dir / "std.npy", np.asarray(std, dtype=np.float32))
    manifest: dict[str, Any] = {
        "format_version": 1, "family": "hifigpt", "name": name, "version": version,
        **motion_fields(vq.config.feat_dim, vq.config.frames_per_token, c.max_tokens),
        "codebook_size": c.codebook_size, "residual_layers": c.depth,
        "hifigpt": {"n_layer_temporal": c.n_layer_temporal, "n_layer_residual": c.n_layer_residual,
                    "n_head": c.n_head, "head_dim": c.head_dim, "block_size": c.block_size,
                    "length_conditioning": bool(c.length_conditioning),
                    "unconditional_branch": bool(unconditional_branch), "default_guidance": float(default_guidance)},
        "text_encoder": text_entry, "training_data": dict(training_data), "license": license,
        "quantization": {"text_encoder": None},
    }
    checks = HiFiGPTExportChecks()
    if check_parity:
        log.info("checking onnxruntime against PyTorch (float32)")
        checks.parity = _parity(out_dir, vq, model, text_source, default_guidance if unconditional_branch else 1.0)
        if encoders:
            checks.parity["encoder"] = encoder_parity(vq, out_dir / ENCODER_FILE, 3)
    _quantize(out_dir, int8, model, manifest, checks, default_guidance if unconditional_branch else 1.0)
    card_notes = "\n\n".join(part for part in (checks.model_card_section(), notes.strip()) if part)
    (out_dir / "MODEL_CARD.md").write_text(render_hifigpt_model_card(manifest, card_notes), encoding="utf-8")
    names = [*GRAPHS, *encoders, "mean.npy", "std.npy", "MODEL_CARD.md"]
    return write_bundle(out_dir, {name: out_dir / name for name in names}, manifest), checks


def _quantize(out_dir: Path, int8: frozenset[str], model: HiFiGPT, manifest: dict[str, Any],
              checks: HiFiGPTExportChecks, guidance: float) -> None:
    """Replace the chosen graphs by int8 ones; the step graphs' price is the export's seeded guided rollout run again
    with the int8 graphs against PyTorch."""
    from t2m.export.writing.quantize import text_int8_report

    def sizes(fp32: Path, quantized: Path) -> dict[str, Any]:
        return {"fp32_bytes": fp32.stat().st_size, "int8_bytes": quantized.stat().st_size}

    if "text" in int8:
        checks.int8["text_encoder"] = quantize_in_place(
            out_dir / "text_encoder.onnx",
            lambda fp32, q: asdict(text_int8_report(fp32, q, out_dir / "tokenizer.json")))
    for key in ("temporal", "residual"):
        if key in int8:
            checks.int8[INT8_GRAPHS[key]] = quantize_in_place(out_dir / f"{INT8_GRAPHS[key]}.onnx", sizes,
                                                              per_row=True)
    for key in int8:
        manifest["quantization"][INT8_GRAPHS[key]] = INT8_LABEL if key == "text" else ROW_INT8_LABEL
    if {"temporal", "residual"} & int8:
        rollout = asdict(rollout_parity(model, out_dir / "temporal_step.onnx", out_dir / "residual_step.onnx",
                                        guidance=guidance))
        float32 = checks.parity.get("rollout", {}).get("steps")
        checks.int8["rollout"] = {**rollout, "steps_identical": float32 is None or rollout["steps"] == float32}


def export_hifigpt_from_runs(
    vq_run: str | Path, hifigpt_run: str | Path, out_dir: str | Path, *, name: str | None = None,
    version: str = "0.1.0", model_card: str | Path | None = None, data_summary: str | Path | None = None,
    default_guidance: float | None = None, check_parity: bool = True, text_source: TextSource | None = None,
    int8: frozenset[str] = frozenset(), encoder: bool = True,
) -> tuple[dict[str, Any], HiFiGPTExportChecks]:
    """A verified hifigpt bundle from a residual vq run and a hifigpt run. ``text_source`` replaces building the
    run's text encoder (tests)."""
    from t2m.export.kit.runs import normalisation as _normalisation
    from t2m.export.kit.runs import run_training_data
    from t2m.export.kit.text_sources import recorded_text_source
    from t2m.model.training.checkpoint import check_trained_on, load_run, read_run_config

    vq_run, hifigpt_run = Path(vq_run), Path(hifigpt_run)
    vq_record, record = read_run_config(vq_run), read_run_config(hifigpt_run)
    for run, found, expected in ((vq_run, vq_record, "vq"), (hifigpt_run, record, "hifigpt")):
        if found["kind"] != expected:
            raise ValueError(f"{run}/config.json: expected a {expected} checkpoint, found {found['kind']!r}")
    check_trained_on(hifigpt_run, vq_run)
    vq = load_run(vq_run, "vq", MotionVQVAE)
    model = load_run(hifigpt_run, "hifigpt", HiFiGPT)
    check_hifigpt_models(vq, model)
    data = record.get("data", {})
    kind, make_text_source = recorded_text_source(hifigpt_run, data, text_source)
    training_data = run_training_data(hifigpt_run, data, vq_record, data_summary)
    cond_drop = float((data.get("training") or {}).get("cond_drop", 0.0))
    guidance = default_guidance if default_guidance is not None else (3.0 if cond_drop > 0 else 1.0)
    mean, std = _normalisation(vq_run, vq_record)
    notes = (f"## Provenance\n\n- VQ run: `{vq_run.name}` (step {vq_record.get('step')})\n"
             f"- HiFiGPT run: `{hifigpt_run.name}` (step {record.get('step')}), condition dropout {cond_drop}, "
             f"corruption {(data.get('training') or {}).get('corruption')} per time step\n")
    if model_card:
        notes += "\n" + Path(model_card).read_text(encoding="utf-8")
    return export_hifigpt_bundle(
        out_dir, vq=vq, model=model, mean=mean, std=std, text_source=make_text_source(),
        name=name or f"t2m-{training_data['name']}-hifigpt-{kind}", version=version, training_data=training_data,
        license=training_data["license"], unconditional_branch=cond_drop > 0, default_guidance=guidance,
        notes=notes, check_parity=check_parity, int8=int8)
