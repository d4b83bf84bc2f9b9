"""An MDM / DiP module (t2m.families.diffusion.network) -> a diffusion-family bundle (t2m/families/diffusion/README.md).

`export_diffusion_bundle` is what the importers (`t2m import mdm|dip`) and the tiny random bundles call: the module's
denoiser graph, the de-normalising decoder, the text graph of a TextSource (pooled features for MDM's CLIP, token
states for DiP's DistilBERT), mean/std, DiP's first prefix, the manifest and the card, hashed and verified by
write_bundle against the family's signatures.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from t2m.bundle.manifest import COMMON_FILES
from t2m.export.kit.checks import INT8_LABEL, quantize_in_place, text_int8_line
from t2m.export.kit.text_sources import TextSource
from t2m.families.diffusion.network import MDM

__all__ = ["MDM_MAX_FRAMES", "PREFIX_FILE", "TRAINED_MAX_FRAMES", "denoiser_parity", "export_diffusion_bundle",
           "export_dip_from_run", "standing_prefix"]

MDM_MAX_FRAMES = 196          # generate.py's limit for HumanML3D / KIT
TRAINED_MAX_FRAMES = 200      # a sentence of a DiP trained here: 10 s, as the embedded models (DiP has no own limit)
PREFIX_FILE = "prefix.npy"
JOIN_FRAMES = 10              # frames made anew on each side of an MDM join (0.5 s at 20 fps)
JOIN_CONTEXT = 10             # known frames kept around them on each side


def standing_prefix(mean: np.ndarray, std: np.ndarray, frames: int) -> np.ndarray:
    """`frames` normalised frames of standing still: the statistics' mean frame (HumanML3D's mean pose, which
    decodes to a symmetric standing pose) with the root's rotation and linear velocities and every joint's local
    velocity set to 0 and the four foot contacts to 1, then normalised; float32 [frames, D]. (The mean frame
    itself is not still: its root velocity is the data's mean, about 8.7 mm per frame forward.)"""
    mean, std = np.asarray(mean, np.float64), np.asarray(std, np.float64)
    dim = len(mean)
    joints = (dim + 1) // 12
    if 12 * joints - 1 != dim:
        raise ValueError(f"feature_dim {dim} is not a HumanML3D layout (12 * joints - 1)")
    still = mean.copy()
    still[0:3] = 0.0                                       # root angular velocity, root linear velocity x/z
    velocities = 4 + 9 * (joints - 1)
    still[velocities:velocities + 3 * joints] = 0.0        # local velocities
    still[-4:] = 1.0                                       # both feet on the ground
    normalised = np.where(std > 0, (still - mean) / np.where(std > 0, std, 1.0), 0.0)
    return np.repeat(normalised[None], frames, axis=0).astype(np.float32)


def export_diffusion_bundle(
    out_dir: str | Path, *, model: MDM, mean: np.ndarray, std: np.ndarray, text_source: TextSource, name: str,
    version: str, training_data: Mapping[str, str], license: str, default_guidance: float,
    unconditional_branch: bool = True, max_frames: int = MDM_MAX_FRAMES, join_frames: int = JOIN_FRAMES,
    join_context: int = JOIN_CONTEXT, prefix: np.ndarray | None = None, crossfade: int = 0,
    description: str = "",
    notes: str = "", checks: Callable[[Path], str] | None = None,
    int8_reports: dict[str, Any] | None = None) -> dict[str, Any]:
    """Write and verify the bundle; returns the written manifest. `max_frames`: the longest segment (MDM: 196; a
    DiP model has no limit of its own: how long one sentence may run); `prefix` [context_len, F] normalised frames
    before DiP's first call (default: standing_prefix of mean/std); `join_frames` / `join_context`: MDM's
    in-between window at each join of sentences (0 join frames: the sentences are put end to end as made);
    `crossfade`: DiP's later sentences cross-fade from the previous text over that many frames (0: the official
    switch);
    `checks(out_dir)`, called once the graphs are written (an importer's parity against its modules), returns
    Markdown the card adds after `notes`; `int8_reports` (a dict): the text graph is quantised to int8 (its
    price, cosine to the float32 states and speed, is put in it under "text_encoder" and on the card)."""
    from t2m.export.writing.bundle import motion_fields, render_family_card, write_bundle
    from t2m.families.diffusion.export_graphs import export_denoiser, export_denormaliser

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    c = model.config
    mean, std = np.asarray(mean, np.float32), np.asarray(std, np.float32)
    if mean.shape != (c.features,) or std.shape != (c.features,):
        raise ValueError(f"mean/std must be [{c.features}], got {mean.shape} / {std.shape}")
    if c.pred_len > 0 and crossfade and not 0 < crossfade <= c.pred_len:
        raise ValueError(f"crossfade must be within 1..{c.pred_len} (one call), got {crossfade}")
    text = text_source.write(out_dir)
    if text["dim"] != c.text_dim:
        raise ValueError(f"the text encoder gives {text['dim']}-d features, the model reads {c.text_dim}")
    export_denoiser(model, out_dir / "denoiser.onnx")
    export_denormaliser(mean, std, out_dir / "decoder.onnx")
    np.save(out_dir / "mean.npy", mean)
    np.save(out_dir / "std.npy", std)
    files: dict[str, str | Path | bytes] = {
        file: out_dir / file for file in (*COMMON_FILES[:2], "denoiser.onnx", *COMMON_FILES[2:-1])}
    chained = c.pred_len > 0
    if chained:
        first = standing_prefix(mean, std, c.context_len) if prefix is None else np.asarray(prefix, np.float32)
        if first.shape != (c.context_len, c.features):
            raise ValueError(f"prefix must be [{c.context_len}, {c.features}], got {first.shape}")
        np.save(out_dir / PREFIX_FILE, first)
        files[PREFIX_FILE] = out_dir / PREFIX_FILE
    if checks is not None:
        notes = notes + "\n" + checks(out_dir)
    quantized_text = None
    if int8_reports is not None:
        int8_reports["text_encoder"] = _quantize_text(out_dir)
        quantized_text = INT8_LABEL
        notes += "\n## int8\n\n" + text_int8_line(int8_reports["text_encoder"]) + "\n"
    block = {"arch": c.arch, "steps": c.diffusion_steps, "default_guidance": float(default_guidance),
             "unconditional_branch": bool(unconditional_branch),
             "text_conditioning": "tokens" if c.text_tokens else "pooled", "mask_frames": c.mask_frames,
             "context_len": c.context_len if chained else 0, "pred_len": c.pred_len if chained else 0,
             "join_frames": 0 if chained else join_frames, "join_context": 0 if chained else join_context,
             "prefix": PREFIX_FILE if chained else None}
    if chained and crossfade:
        block["crossfade"] = int(crossfade)
    manifest: dict[str, Any] = {
        "family": "diffusion", "name": name, "version": version, **motion_fields(c.features, 1, max_frames),
        "codebook_size": 1, "residual_layers": 1, "text_encoder": text, "diffusion": block,
        "training_data": dict(training_data), "license": license,
        "quantization": {"text_encoder": quantized_text, "denoiser": None}}
    fade = (f"; a later sentence's first call cross-fades from the previous text over {crossfade} frames"
            if chained and crossfade else "")
    how = (f"{c.pred_len}-frame calls after {c.context_len} clean frames, each sentence its own calls; the first "
           f"call continues a standing pose (prefix.npy){fade}" if chained else
           f"each sentence a whole motion of at most {max_frames} frames; joins re-made by in-betweening "
           f"({join_frames} frames a side after {join_context} known)")
    rows = [("denoiser", f"{c.arch}, {c.layers} layers, latent {c.latent_dim}, x0 prediction, {c.diffusion_steps} "
                         f"DDPM steps (cosine), guidance {default_guidance:g}"), ("sentences", how)]
    card = render_family_card(manifest, description or "A diffusion-family bundle (MDM / DiP): denoiser.onnx "
                              "stepped by DDPM ancestral sampling, decoder.onnx de-normalises the frames.", rows,
                              notes)
    (out_dir / "MODEL_CARD.md").write_text(card, encoding="utf-8")
    files["MODEL_CARD.md"] = out_dir / "MODEL_CARD.md"
    return write_bundle(out_dir, files, manifest)


def _quantize_text(out_dir: Path) -> dict[str, Any]:
    """text_encoder.onnx -> int8 dynamic in place; returns its measured price (quantize.TextInt8Report)."""
    from dataclasses import asdict

    from t2m.export.writing.quantize import text_int8_report

    return quantize_in_place(out_dir / "text_encoder.onnx",
                             lambda fp32, q: asdict(text_int8_report(fp32, q, out_dir / "tokenizer.json")))


def denoiser_parity(model: MDM, graph: str | Path, seed: int = 0) -> float:
    """Largest |onnxruntime - PyTorch| of the denoiser graph on a random DiP/MDM input (two rows, all steps' ends)."""
    import onnxruntime as ort
    import torch

    from t2m.families.diffusion.export_graphs import denoiser_inputs

    c = model.config
    rng = np.random.default_rng(seed)
    frames = c.pred_len or 8
    inputs: dict[str, np.ndarray] = {
        "x_t": rng.normal(size=(2, frames, c.features)).astype(np.float32),
        "t": np.array([c.diffusion_steps - 1, 0], np.int64),
        "text": rng.normal(size=(2, 5, c.text_dim) if c.text_tokens else (2, c.text_dim)).astype(np.float32),
        "text_mask": np.array([[True] * 5, [True] * 3 + [False] * 2]),
        "length": np.array([frames, frames], np.int64),
        "prefix": rng.normal(size=(2, max(c.context_len, 1), c.features)).astype(np.float32)}
    names = denoiser_inputs(model)
    session = ort.InferenceSession(str(graph), providers=["CPUExecutionProvider"])
    (served,) = session.run(["x0"], {name: inputs[name] for name in names})
    with torch.no_grad():
        given = {name: torch.from_numpy(inputs[name]) for name in names}
        expected = model.eval()(given["x_t"], given["t"], given["text"], given.get("text_mask"),
                                given.get("length"), given.get("prefix")).numpy()
    return float(np.abs(served - expected).max())


def export_dip_from_run(run: str | Path, out_dir: str | Path, *, name: str | None = None, version: str = "0.1.0",
                        default_guidance: float | None = None, model_card: str | Path | None = None,
                        data_summary: str | Path | None = None, text_source: TextSource | None = None,
                        check_parity: bool = True, int8_text: bool = False,
                        crossfade: int = 0) -> tuple[dict[str, Any], dict[str, Any]]:
    """A `t2m train dip` run -> a DiP bundle: its EMA weights (model_avg), the MiniLM token-state text graph it was
    trained on (`text_source` replaces it in tests; int8 with `int8_text`), the run's mean/std, the standing prefix;
    returns (manifest, checks). `crossfade`: see export_diffusion_bundle."""
    from t2m.export.kit.runs import run_training_data
    from t2m.export.kit.text_sources import token_states_text_source
    from t2m.families.diffusion.network import AveragedMDM
    from t2m.families.diffusion.text_encoders import minilm_token_encoder
    from t2m.model.training.checkpoint import load_model, read_run_config

    run = Path(run)
    record = read_run_config(run)
    if record["kind"] != "dip":
        raise ValueError(f"{run}/config.json: expected a dip checkpoint (t2m train dip), found {record['kind']!r}")
    averaged = load_model(run, expect_kind="dip")
    assert isinstance(averaged, AveragedMDM)
    model = averaged.model_avg.eval()
    data = record.get("data", {})
    text = data.get("text_encoder") or {}
    if text_source is None:
        if text.get("kind") != "minilm-tokens":
            raise ValueError(f"{run}: trained on {text.get('kind')!r} token states; only minilm-tokens is exported")
        text_source = token_states_text_source(minilm_token_encoder())
    mean, std = np.load(run / "mean.npy"), np.load(run / "std.npy")
    training_data = run_training_data(run, data, {}, data_summary)
    training = data.get("training", {})
    guidance = 2.5 if default_guidance is None else float(default_guidance)
    notes = ("## Provenance\n\n"
             f"- dip run: `{run.name}` (step {record.get('step')}), EMA weights (decay {training.get('ema_decay')}), "
             f"condition dropout {training.get('cond_mask_prob')}, {text.get('kind')} token states\n")
    if model_card:
        notes += "\n" + Path(model_card).read_text(encoding="utf-8")
    c = model.config
    int8: dict[str, Any] | None = {} if int8_text else None
    manifest = export_diffusion_bundle(
        out_dir, model=model, mean=mean, std=std, text_source=text_source,
        name=name or f"t2m-{training_data['name']}-dip-minilm", version=version, training_data=training_data,
        license=training_data["license"], default_guidance=guidance,
        unconditional_branch=float(training.get("cond_mask_prob", 0.0)) > 0, max_frames=TRAINED_MAX_FRAMES,
        crossfade=crossfade,
        description=f"A small DiP trained here ({c.layers} decoder layers, latent {c.latent_dim}) on "
                    f"{training_data['name']}: {c.pred_len}-frame calls after {c.context_len} frames, "
                    f"{c.diffusion_steps} DDPM steps, MiniLM token states.", notes=notes, int8_reports=int8)
    parity = denoiser_parity(model, Path(out_dir) / "denoiser.onnx") if check_parity else None
    return manifest, {"parity": {"denoiser_max_abs": parity} if parity is not None else "skipped", "int8": int8 or {}}
