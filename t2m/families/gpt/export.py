"""The GPT family's exporter: a bundle from PyTorch modules (``export_bundle``) or from our training runs
(``export_from_runs``).

``export_bundle`` is shared by the three producers of bundles: our runs (``t2m export``), the
T2M-GPT importer (``t2m import t2m-gpt``) and the random test bundle. It exports the three graphs,
checks them against PyTorch (float32 parity; optional), optionally quantises some of them to int8
(and measures what that costs), writes mean/std, the tokenizer and a model card that records those
numbers, and hands everything to :func:`export.bundle.write_bundle`, which hashes and verifies.
"""
from __future__ import annotations

import logging
import os
import shutil
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from t2m.bundle.graphs import FIXED_STEP_GRAPH
from t2m.export.graphs.decoder import export_decoder
from t2m.export.graphs.encoder import ENCODER_FILE, encoder_card_lines, encoder_parity, write_encoder
from t2m.export.kit.checks import GROSS_PARITY_ERROR, INT8_LABEL, ROW_INT8_LABEL, quantize_in_place, text_int8_line
from t2m.export.kit.runs import normalisation, run_record, run_training_data
from t2m.export.kit.text_sources import TextSource, clip_text_source, minilm_text_source
from t2m.export.writing.bundle import check_out_dir, motion_fields, prepare_out_dir, render_model_card, write_bundle
from t2m.families.gpt.export_graphs import export_gpt_fixed_cache_step, export_gpt_step
from t2m.families.gpt.network import MotionGPT
from t2m.model.networks.vqvae import MotionVQVAE

log = logging.getLogger(__name__)

INT8_CHOICES = ("none", "text", "gpt", "all")


def check_int8_choice(int8: str) -> None:
    if int8 not in INT8_CHOICES:
        raise ValueError(f"--int8 must be one of {', '.join(INT8_CHOICES)}, got {int8!r}")


@dataclass
class ExportChecks:
    """What export measured: float32 parity against PyTorch and, per quantised graph, the int8 report."""

    parity: dict[str, Any] = field(default_factory=dict)
    int8: dict[str, Any] = field(default_factory=dict)
    quantization: dict[str, Any] | None = None   # the import's --quantize report (t2m.export.writing.int8)

    def model_card_section(self) -> str:
        lines: list[str] = []
        if self.parity:
            gpt, dec = self.parity["gpt_step"], self.parity["decoder"]
            lines += [
                "## Export checks (onnxruntime vs PyTorch, float32)",
                "",
                f"- GPT step graph: {gpt['steps']}-step greedy rollout, guidance {gpt['guidance']}: max |logit diff|"
                f" {gpt['max_abs_logit_diff']:.2e}; code sequences identical: {gpt['codes_identical']};"
                f" vs full-prefix recomputation {gpt['max_abs_diff_vs_recompute']:.2e}",
                f"- decoder: max |feature diff| {dec['max_abs_diff']:.2e}",
            ]
            if "text_encoder" in self.parity:
                lines.append(f"- text encoder: max |feature diff| {self.parity['text_encoder']['max_abs_diff']:.2e}")
            lines += [*encoder_card_lines(self.parity), ""]
        if self.int8:
            which = " and ".join({"gpt_step": "the GPT step", "text_encoder": "the text encoder"}.get(name, name)
                                 for name in self.int8)
            lines += ["## int8 dynamic quantisation (vs the float32 graphs)", "",
                      f"int8 (chosen with `--int8` at export): {which}; every other graph is float32. Why: a step "
                      "reads each weight once, so fewer bytes per weight is what makes it faster and the file smaller; "
                      "weights keep 7 bits so that CPUs with and without VNNI compute the same integers. The price, "
                      "measured against the float32 graphs:", ""]
            if "gpt_step" in self.int8:
                r = self.int8["gpt_step"]
                lines.append(
                    f"- GPT step: max |logit diff| {r['max_abs_logit_diff']:.3f}; greedy codes identical over"
                    f" {r['steps']} steps: {r['greedy_codes_match']}; {r['fp32_ms_per_step']:.2f} -> "
                    f"{r['int8_ms_per_step']:.2f} ms/step;"
                    f" {r['fp32_bytes'] / 1e6:.1f} -> {r['int8_bytes'] / 1e6:.1f} MB")
            if "text_encoder" in self.int8:
                lines.append(text_int8_line(self.int8["text_encoder"]))
            lines.append("")
        return "\n".join(lines)


def _check_parity(parity: dict[str, Any]) -> None:
    worst = {"gpt_step": parity["gpt_step"]["max_abs_logit_diff"], "decoder": parity["decoder"]["max_abs_diff"]}
    if "text_encoder" in parity:
        worst["text_encoder"] = parity["text_encoder"]["max_abs_diff"]
    for graph, diff in worst.items():
        if not diff <= GROSS_PARITY_ERROR:
            raise ValueError(f"{graph}.onnx differs from PyTorch by {diff:.3g} (> {GROSS_PARITY_ERROR}); not exported")
    if not parity["gpt_step"]["codes_identical"]:
        log.warning("gpt_step.onnx: greedy codes differ from PyTorch's (near-tie logits?): %s", parity["gpt_step"])


def export_bundle(
    out_dir: str | Path,
    *,
    vq: MotionVQVAE,
    gpt: MotionGPT,
    mean: np.ndarray,
    std: np.ndarray,
    text_source: TextSource,
    name: str,
    version: str,
    unconditional_branch: bool,
    default_guidance: float,
    training_data: Mapping[str, str],
    license: str,
    int8: str = "none",
    notes: str = "",
    check_parity: bool = False,
    parity_steps: int = 50,
    encoder: bool = True,
    fixed_step: bool = False,
) -> tuple[dict, ExportChecks]:
    """Export ``vq`` + ``gpt`` + a text encoder as a verified bundle in ``out_dir``; return (manifest, checks).
    ``fixed_step`` adds gpt_step_fixed.onnx, the step that T2M_CUDA_GRAPHS replays (a second float32 copy of the
    GPT's weights).

    Everything is built and verified in a sibling staging directory first and moved into ``out_dir``
    only when complete, so a failed export leaves neither a half bundle nor a damaged earlier one.
    """
    check_int8_choice(int8)
    if vq.config.nb_code != gpt.config.codebook_size:
        raise ValueError(f"VQ codebook ({vq.config.nb_code}) and GPT codebook_size ({gpt.config.codebook_size}) differ")
    out_dir = check_out_dir(out_dir)
    staging = out_dir.parent / f".{out_dir.name}.partial-{os.getpid()}"
    if staging.exists():
        shutil.rmtree(staging)
    staging.mkdir(parents=True)
    try:
        manifest, checks = _export_into(
            staging, vq=vq.eval(), gpt=gpt.eval(), mean=mean, std=std, text_source=text_source, name=name,
            version=version, unconditional_branch=unconditional_branch, default_guidance=default_guidance,
            training_data=training_data, license=license, int8=int8, notes=notes, check_parity=check_parity,
            parity_steps=parity_steps, encoder=encoder, fixed_step=fixed_step)
        prepare_out_dir(out_dir)
        for file in sorted(staging.iterdir(), key=lambda f: f.name == "manifest.json"):  # manifest last
            file.replace(out_dir / file.name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return manifest, checks


def _export_into(
    out_dir: Path, *, vq: MotionVQVAE, gpt: MotionGPT, mean: np.ndarray, std: np.ndarray, text_source: TextSource,
    name: str, version: str, unconditional_branch: bool, default_guidance: float, training_data: Mapping[str, str],
    license: str, int8: str, notes: str, check_parity: bool, parity_steps: int, encoder: bool = True,
    fixed_step: bool = False,
) -> tuple[dict, ExportChecks]:
    from t2m.export.writing.quantize import text_int8_report
    from t2m.families.gpt.parity import bundle_parity, gpt_int8_report

    log.info("exporting the text encoder")
    text_entry = text_source.write(out_dir)
    if text_entry["dim"] != gpt.config.text_dim:
        raise ValueError(f"text encoder dim {text_entry['dim']} != GPT text_dim {gpt.config.text_dim}")
    log.info("exporting the GPT step graph")
    export_gpt_step(gpt, out_dir / "gpt_step.onnx")
    if fixed_step:
        log.info("exporting the fixed-capacity step graph (CUDA graphs)")
        export_gpt_fixed_cache_step(gpt, out_dir / FIXED_STEP_GRAPH)
    log.info("exporting the decoder")
    export_decoder(vq, mean, std, out_dir / "decoder.onnx")
    rank = 2 if vq.config.quantizer != "residual" else 3   # the decoder's codes: [B, T] or [B, T, R]
    encoders = write_encoder(vq, out_dir, rank) if encoder else []
    np.save(out_dir / "mean.npy", np.asarray(mean, dtype=np.float32))
    np.save(out_dir / "std.npy", np.asarray(std, dtype=np.float32))

    c = gpt.config
    manifest: dict[str, Any] = {
        "format_version": 1,
        "name": name,
        "version": version,
        **motion_fields(vq.config.feat_dim, vq.config.frames_per_token, c.max_tokens),
        "codebook_size": c.codebook_size,
        "residual_layers": vq.config.residual_layers if vq.config.quantizer == "residual" else 1,
        "end_id": c.end_id,
        "gpt": {"n_layer": c.n_layer, "n_head": c.n_head, "head_dim": c.head_dim, "block_size": c.block_size,
                "length_conditioning": bool(c.length_conditioning),
                "unconditional_branch": bool(unconditional_branch), "default_guidance": float(default_guidance)},
        "text_encoder": text_entry,
        "training_data": dict(training_data),
        "license": license,
        "quantization": {"text_encoder": None, "gpt_step": None},
    }
    checks = ExportChecks()
    if check_parity:
        log.info("checking onnxruntime against PyTorch (float32)")
        checks.parity = bundle_parity(out_dir, vq, gpt, text_source.encoder,
                                      guidance=3.0 if unconditional_branch else 1.0, steps=parity_steps)
        if encoders:
            checks.parity["encoder"] = encoder_parity(vq, out_dir / ENCODER_FILE, rank)
        _check_parity(checks.parity)
    if int8 in ("all", "text"):
        checks.int8["text_encoder"] = quantize_in_place(
            out_dir / "text_encoder.onnx",
            lambda fp32, q: asdict(text_int8_report(fp32, q, out_dir / "tokenizer.json")))
        manifest["quantization"]["text_encoder"] = INT8_LABEL
    if int8 in ("all", "gpt"):
        checks.int8["gpt_step"] = quantize_in_place(
            out_dir / "gpt_step.onnx", lambda fp32, q: asdict(gpt_int8_report(fp32, q, manifest)), per_row=True)
        manifest["quantization"]["gpt_step"] = ROW_INT8_LABEL
    card_notes = "\n\n".join(part for part in (checks.model_card_section(), notes.strip()) if part)
    (out_dir / "MODEL_CARD.md").write_text(render_model_card(manifest, card_notes), encoding="utf-8")
    files = {file: out_dir / file for file in
             ("text_encoder.onnx", "tokenizer.json", "gpt_step.onnx", "decoder.onnx", "mean.npy", "std.npy",
              "MODEL_CARD.md", *encoders, *([FIXED_STEP_GRAPH] if fixed_step else []))}
    return write_bundle(out_dir, files, manifest), checks


def export_from_runs(
    vq_run: str | Path,
    gpt_run: str | Path,
    out_dir: str | Path,
    *,
    text_encoder: str | None = None,
    clip_weights: str | Path | None = None,
    int8: str = "none",
    name: str | None = None,
    version: str = "0.1.0",
    model_card: str | Path | None = None,
    data_summary: str | Path | None = None,
    default_guidance: float | None = None,
    check_parity: bool = True,
    text_source: TextSource | None = None,
) -> tuple[dict, ExportChecks]:
    """A verified bundle from a VQ run and a GPT run (t2m.model.training.checkpoint layout).

    ``text_source`` replaces building the run's text encoder (tests pass an already loaded MiniLM).
    """
    from t2m.model.training.checkpoint import check_trained_on, load_model

    check_int8_choice(int8)
    vq_run, gpt_run = Path(vq_run), Path(gpt_run)
    vq_record, gpt_record = run_record(vq_run), run_record(gpt_run)
    for run, record, expected in ((vq_run, vq_record, "vq"), (gpt_run, gpt_record, "gpt")):
        if record["kind"] != expected:
            raise ValueError(f"{run}/config.json: expected a {expected} checkpoint, found {record['kind']!r}")
    gpt_data = gpt_record.get("data", {})
    check_trained_on(gpt_run, vq_run)
    run_text = (gpt_data.get("text_encoder") or {}).get("kind")
    kind = text_encoder or run_text or "minilm"
    if run_text and kind != run_text:
        raise ValueError(f"--text-encoder {kind}: the GPT run was trained with the {run_text} text encoder")
    if kind not in ("minilm", "clip"):
        raise ValueError(f"--text-encoder must be minilm or clip, got {kind!r}")
    if kind == "clip":
        clip_weights = clip_weights or gpt_data.get("text_encoder", {}).get("clip_weights")
        if not clip_weights:
            raise ValueError("--clip-weights is required for the clip text encoder")

    training_data = run_training_data(gpt_run, gpt_data, vq_record, data_summary)
    cond_drop = float((gpt_data.get("training") or {}).get("cond_drop", 0.0))
    unconditional = cond_drop > 0
    guidance = default_guidance if default_guidance is not None else (3.0 if unconditional else 1.0)
    mean, std = normalisation(vq_run, vq_record)
    notes = (f"## Provenance\n\n- VQ run: `{vq_run.name}` (step {vq_record.get('step')})\n"
             f"- GPT run: `{gpt_run.name}` (step {gpt_record.get('step')}), condition dropout {cond_drop}\n")
    if model_card:
        notes += "\n" + Path(model_card).read_text(encoding="utf-8")
    vq = load_model(vq_run, expect_kind="vq")
    gpt = load_model(gpt_run, expect_kind="gpt")
    assert isinstance(gpt, MotionGPT)
    if text_source is None:  # built last: loading a text encoder is the slow part
        text_source = (clip_text_source(clip_weights) if kind == "clip" and clip_weights is not None
                       else minilm_text_source())
    return export_bundle(
        out_dir, vq=vq, gpt=gpt, mean=mean, std=std, text_source=text_source,
        name=name or f"t2m-{training_data['name']}-{kind}", version=version,
        unconditional_branch=unconditional, default_guidance=guidance, training_data=training_data,
        license=training_data["license"], int8=int8, notes=notes, check_parity=check_parity,
    )
